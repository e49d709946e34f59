"""The emulated load cell: signal and line formats, and its in-process and pty transports."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "artefacts",
    "emulator",
    "inprocess_line",
    "line_pty_server",
    "profiles",
]
