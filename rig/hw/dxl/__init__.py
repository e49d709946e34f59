"""Dynamixel X-series over Protocol 2.0: control tables, units, error decoding, transport, bus, scan."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "bus",
    "control_table",
    "discovery",
    "error_codes",
    "setup",
    "transport",
    "units",
)

# The names users import (`from rig.hw.dxl import BusStats`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "BusStats": "transport",
    "DynamixelServoBus": "bus",
    "scan_port": "discovery",
    "ScannedServo": "discovery",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
