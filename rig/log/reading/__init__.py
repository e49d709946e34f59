"""Reading logs: bounded MCAP scanning, the tolerant run reader and payloads as columns."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "reader",
]
