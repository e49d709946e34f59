"""Configuration sources a rig config can choose (`configuration.source:`), and the factory for them."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "factory",
]
