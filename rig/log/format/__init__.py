"""The log format: its version, the topic schemas, the 3D scene payloads and one example per topic."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "examples",
    "link_scene",
    "log_format",
    "schemas",
    "viewer_schema",
]
