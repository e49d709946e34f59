"""The Foxglove server's address options, shared by `rig run --live` and `rig replay --serve`."""

from __future__ import annotations

import argparse

DEFAULT_LIVE_PORT = 8765
DEFAULT_LIVE_HOST = "127.0.0.1"  # this computer only, unless told otherwise


def add_live_address(parser: argparse.ArgumentParser, flag: str) -> None:
    """Add `--live-port` and `--live-host` for the server that `flag` starts."""
    parser.add_argument(
        "--live-port",
        type=int,
        default=DEFAULT_LIVE_PORT,
        metavar="PORT",
        help=f"{flag} port (default {DEFAULT_LIVE_PORT}; 0: any free one)",
    )
    parser.add_argument(
        "--live-host",
        default=DEFAULT_LIVE_HOST,
        metavar="HOST",
        help=f"address {flag} binds (default {DEFAULT_LIVE_HOST}: this computer only)",
    )
