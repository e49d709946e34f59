"""The emulated Dynamixel bus: Protocol 2.0 framing, servos with their control tables, transports."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "actuator",
    "bus_pty_server",
    "emulated_bus",
    "faults",
    "inprocess_port",
    "packet1",
    "servo",
    "shaft_motion",
)

# The names users import (`from rig.sim.dxl import EmulatedBus`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "EmulatedBus": "emulated_bus",
    "SimPortHandler": "inprocess_port",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
