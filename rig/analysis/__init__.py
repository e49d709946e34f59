"""Replay and analysis of logged runs: trial tables, re-detection, refits and reports (`rig replay`)."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "redetect",
    "replay",
    "report",
    "summary",
]
