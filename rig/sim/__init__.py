"""Simulation: the virtual clock, the simulated world and the byte-level device emulators."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
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
)

# The names users import (`from rig.sim import PtyPort`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "build_twin": "twin",
    "PtyPort": "pty_port",
    "serve_twin": "twin",
    "SimulatedRig": "simulated_rig",
    "VirtualClock": "virtual_clock",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
