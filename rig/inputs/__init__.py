"""The input files: protocols, rig configs, link files, and the parsing and validation they share."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "files",
    "linkfile",
    "protocol",
    "rig_config",
    "servo_ratings",
    "validate",
]
