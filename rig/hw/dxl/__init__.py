"""Dynamixel X-series over Protocol 2.0: control tables, units, error decoding, transport, bus, scan."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "bus",
    "control_table",
    "discovery",
    "error_codes",
    "setup",
    "transport",
    "units",
]
