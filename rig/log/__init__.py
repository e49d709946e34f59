"""MCAP logging, by job: the format (topic schemas), writing, the live view and reading."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "format",
    "live",
    "reading",
    "writing",
]
