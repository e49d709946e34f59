"""The simulated world: the test article, its joints and slips, the winch line and the bending fixture."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "configuration_source",
    "link_presets",
    "world",
]
