"""The serial load cell: line formats, the pyserial driver, calibration and device-clock mapping."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "calibration",
    "driver",
    "formats",
)

# The names users import (`from rig.hw.loadcell import Calibration`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "Calibration": "calibration",
    "SerialLoadCell": "driver",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
