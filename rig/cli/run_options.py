"""The arguments that say what to run and on which rig, shared by `rig run` and `rig study`."""

from __future__ import annotations

import argparse
from pathlib import Path

from rig.rig_config import DEFAULT_RIG_CONFIG


def add_protocol_and_rig(parser: argparse.ArgumentParser, *, simulated_only: bool = False) -> None:
    """Add the PROTOCOL argument and `--rig CONFIG` (`simulated_only`: the command needs a simulated rig)."""
    parser.add_argument(
        "protocol", type=Path, metavar="PROTOCOL", help="protocol YAML (see protocols/README.md)"
    )
    what = "simulated rig config YAML" if simulated_only else "rig config YAML"
    parser.add_argument(
        "--rig",
        type=Path,
        default=None,
        metavar="CONFIG",
        help=f"{what} (default: the built-in simulated rig, {DEFAULT_RIG_CONFIG})",
    )
