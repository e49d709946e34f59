"""The serial load cell: line formats, the pyserial driver, calibration and device-clock mapping."""
