"""Simulation: the virtual clock, the simulated world and the byte-level device emulators."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "clock",
    "kinds",
    "pty_link",
    "settings",
    "simulated_rig",
    "truth",
    "twin",
    "twin_console",
    "twin_firmware",
    "twin_ports",
]
