"""The arguments that say what to run and on which rig, shared by `rig run` and `rig study`."""

from __future__ import annotations

import argparse
from pathlib import Path

from rig.inputs.rig_config import DEFAULT_RIG_CONFIG


def add_protocol_and_rig(
    parser: argparse.ArgumentParser, *, simulated_only: bool = False, resumable: bool = False
) -> None:
    """Add the PROTOCOL argument and `--rig CONFIG` (`simulated_only`: the command needs a simulated rig).

    `resumable`: PROTOCOL may be left out (the command checks that `--resume` is given), and both
    default to the run's files on a resume.
    """
    protocol_help = "protocol YAML (see protocols/README.md)"
    if resumable:
        protocol_help += "; with --resume, the run's own by default"
    if resumable:
        parser.add_argument(
            "protocol", type=Path, nargs="?", default=None, metavar="PROTOCOL", help=protocol_help
        )
    else:
        parser.add_argument("protocol", type=Path, metavar="PROTOCOL", help=protocol_help)
    what = "simulated rig config YAML" if simulated_only else "rig config YAML"
    default = f"the built-in simulated rig, {DEFAULT_RIG_CONFIG}"
    if resumable:
        default += "; with --resume, the run's own"
    parser.add_argument(
        "--rig",
        type=Path,
        default=None,
        metavar="CONFIG",
        help=f"{what} (default: {default})",
    )
