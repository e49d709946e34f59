"""Hardware seams and the real drivers: servo bus on dynamixel-sdk, load cell on pyserial."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "bending",
    "clock",
    "hardware_rig",
    "seams",
    "session",
    "usb_latency",
]
