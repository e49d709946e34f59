"""`rig ports`: list the host's serial ports (pyserial's `serial.tools.list_ports`)."""

from __future__ import annotations

import argparse

from serial.tools import list_ports

from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table

DESCRIPTION = """\
List the serial ports pyserial finds on this host, with their descriptions and USB IDs, to find
the U2D2 (Dynamixel bus) and the load cell's adapter. Pseudo-terminals made by `rig sim` are not
listed; use their link path directly.
"""

EPILOG = """\
JSON (--json): {"ports": [{"device", "description", "hwid", "vid", "pid", "serial_number",
"manufacturer"}, ...]} (USB fields are null for non-USB ports). Exit code 0.
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig ports`."""
    parser = subparsers.add_parser(
        "ports",
        help=COMMANDS["ports"],
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Print the serial ports."""
    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    records = [
        {
            "device": p.device,
            "description": p.description,
            "hwid": p.hwid,
            "vid": p.vid,
            "pid": p.pid,
            "serial_number": p.serial_number,
            "manufacturer": p.manufacturer,
        }
        for p in ports
    ]
    if args.json:
        emit_json({"ports": records})
        return 0
    if not records:
        print("no serial ports found")
        return 0
    print(
        format_table(
            ["device", "description", "hwid"], [[r["device"], r["description"], r["hwid"]] for r in records]
        )
    )
    return 0
