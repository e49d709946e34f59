"""The serial load cell: line formats, the pyserial driver, calibration and device-clock mapping."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "calibration",
    "driver",
    "formats",
]
