"""Simulation: the virtual clock, the simulated world and the byte-level device emulators."""
