"""Keeping the rig safe: the safe-state sequence, the line's release, the interlocks and Ctrl-C deferral."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "interlocks",
    "interrupts",
    "release",
    "safe_state",
]
