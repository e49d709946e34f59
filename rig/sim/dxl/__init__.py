"""The emulated Dynamixel bus: Protocol 2.0 framing, servos with their control tables, transports."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "actuator",
    "bus_pty_server",
    "emulated_bus",
    "faults",
    "inprocess_port",
    "packet1",
    "servo",
    "shaft_motion",
]
