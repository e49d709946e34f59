"""Hardware seams and the real drivers: servo bus on dynamixel-sdk, load cell on pyserial."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "bending",
    "clock",
    "hardware_rig",
    "seams",
    "session",
    "usb_latency",
)

# The names users import (`from rig.hw import Clock`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "Clock": "seams",
    "ConfigurationSource": "seams",
    "hardware_session": "hardware_rig",
    "LoadCell": "seams",
    "LoadCellSample": "seams",
    "Operator": "session",
    "OperatorRequest": "session",
    "RigSession": "session",
    "ServoBus": "seams",
    "ServoState": "seams",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
