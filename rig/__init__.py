"""The slip-trial rig: hardware, simulation, protocol runner, MCAP logging and the `rig` CLI."""

__version__ = "0.1.0"
