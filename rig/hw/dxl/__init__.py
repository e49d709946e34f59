"""Dynamixel X-series over Protocol 2.0: control tables, units, error decoding and the servo bus."""
