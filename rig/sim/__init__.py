"""Simulation: the virtual clock, the simulated world and the byte-level device emulators."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "kinds",
    "pty_port",
    "settings",
    "simulated_rig",
    "truth",
    "twin",
    "twin_console",
    "twin_firmware",
    "twin_ports",
    "virtual_clock",
]
