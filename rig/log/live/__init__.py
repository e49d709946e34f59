"""The live view: the run's topics served over the Foxglove WebSocket protocol."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "publisher",
]
