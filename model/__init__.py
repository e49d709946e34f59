"""Pure physics and estimation for the preloaded spherical-joint link (SI units, no I/O, no clock)."""
