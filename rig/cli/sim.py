"""`rig sim DEVICE`: serve byte-level emulated devices on a pty until killed."""

from __future__ import annotations

import argparse
import importlib

from rig.cli.commands import COMMANDS

# Each module `rig.cli.<name>` defines `register(sim_subparsers)` for one emulated device.
SIM_DEVICE_MODULES: tuple[str, ...] = ("sim_loadcell", "sim_servos", "sim_rig")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig sim` and its device subcommands."""
    parser = subparsers.add_parser(
        "sim",
        help=COMMANDS["sim"],
        description=(
            "Serve byte-level emulated devices on a pseudo-terminal, symlinked at --link, until "
            "killed (SIGTERM/SIGINT exit cleanly and remove the link). Point the real drivers, "
            "or any serial client, at the link."
        ),
    )
    devices = parser.add_subparsers(title="devices", metavar="DEVICE", parser_class=type(parser))
    for name in SIM_DEVICE_MODULES:
        importlib.import_module(f"rig.cli.{name}").register(devices)
