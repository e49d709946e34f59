"""The `rig` commands and the line `rig --help` lists for each; every command is the module of its name.

Kept apart from the command modules so that `rig --help`, and the parser of the one command a
`rig` invocation names, are built without importing the other commands (and what they import).
"""

from __future__ import annotations

# Each module `rig.cli.<name>` (a `-` in the command is a `_` in the module) defines
# `register(subparsers)`, which adds its parser, with the summary here as its help, and sets
# `handler=<callable(args) -> int>` as a default.
COMMANDS: dict[str, str] = {
    "run": "run a protocol of slip trials (default: on the built-in simulated rig)",
    "fit": "fit m = k/l to joint-estimation data; joint capacity and mu_s*delta0 with bounds",
    "predict": "predict joint moments, slip load and link capacity from a link file",
    "sim": "serve emulated servos or a load cell on a pty (for trying drivers without a rig)",
    "scan": "find the Dynamixel servos on a serial port (broadcast ping per baud rate)",
    "ports": "list serial ports with descriptions",
    "calibrate": "two-point load-cell calibration (tare + reference mass) written as JSON",
    "check": "pre-flight check of a rig: ports, servos, load cell, slack line, limits (--move: a jog)",
    "replay": "replay MCAP logs: trial table, re-detection, offline refit, Table IV/V, report",
    "study": "run a protocol over many seeds on the simulated rig; coverage, bias, MSE/CRLB per estimator",
    "camera": "camera tools for the camera configuration source (needs the camera extra)",
    "config": "link configurations: measure them from camera images (needs the camera extra)",
    "setup-servos": "set each servo's ID and baud rate, connecting one servo at a time",
}


def module_name(command: str) -> str:
    """The module that defines `command`."""
    return f"rig.cli.{command.replace('-', '_')}"
