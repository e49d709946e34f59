"""Dynamixel X-series over Protocol 2.0: control tables, units, error decoding, transport, bus, scan."""
