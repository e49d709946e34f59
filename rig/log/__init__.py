"""MCAP logging: topic schemas, the queued writer and the tolerant reader."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "frames",
    "link_scene",
    "live",
    "reader",
    "records",
    "schemas",
    "writer",
]
