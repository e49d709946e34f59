"""`rig scan --port PORT`: find the Dynamixel servos on a port by broadcast ping at each baud rate."""

from __future__ import annotations

import argparse
import os
import time

from rig.cli.output import emit_json, format_table
from rig.errors import InputError
from rig.hw.dxl.control_table import SDK_BAUDS
from rig.hw.dxl.scan import scan_port

DEFAULT_BAUDS = (57_600, 1_000_000)

DESCRIPTION = """\
Broadcast-ping the Dynamixel bus (Protocol 2.0) on PORT at each --baud and list every servo that
answers with its ID, model and firmware version. dynamixel-sdk waits its whole broadcast window
whatever answers, so each baud rate takes about a second (0.8 s at 1 Mbps, 1.4 s at 57600).
"""

EPILOG = """\
JSON (--json): {"port": PORT, "servos": [{"id", "model_number", "model", "firmware", "baud"}, ...]}.
Exit codes: 0 done (also when nothing answered); 1 the port could not be used; 2 invalid input
(e.g. the port does not exist, or a baud rate the SDK cannot set).
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig scan`."""
    parser = subparsers.add_parser(
        "scan",
        help="find the Dynamixel servos on a serial port (broadcast ping per baud rate)",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--port", required=True, help="serial port, e.g. /dev/ttyUSB0 (see `rig ports`)")
    parser.add_argument(
        "--baud",
        type=int,
        action="append",
        metavar="B",
        help=f"baud rate to scan; repeat for several (default: {' and '.join(map(str, DEFAULT_BAUDS))})",
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Scan and print the servos found."""
    port = args.port
    bauds = tuple(dict.fromkeys(args.baud)) if args.baud else DEFAULT_BAUDS
    for baud in bauds:
        if baud not in SDK_BAUDS:
            raise InputError(f"--baud {baud}: not a baud rate dynamixel-sdk can set; allowed: {SDK_BAUDS}")
    if "://" not in port and not os.path.exists(port):
        raise InputError(f"--port {port}: no such serial port (see `rig ports`)")
    started = time.monotonic()
    servos = scan_port(port, bauds)
    elapsed_s = time.monotonic() - started
    if args.json:
        servo_records = [
            {
                "id": s.servo_id,
                "model_number": s.model_number,
                "model": s.model,
                "firmware": s.firmware,
                "baud": s.baud,
            }
            for s in servos
        ]
        emit_json({"port": port, "servos": servo_records})
        return 0
    scanned = ", ".join(str(b) for b in bauds)
    if not servos:
        print(f"{port}: no servos answered at {scanned} baud ({elapsed_s:.1f} s)")
        return 0
    rows = [[s.servo_id, s.model, s.model_number, s.firmware, s.baud] for s in servos]
    print(format_table(["id", "model", "model number", "firmware", "baud"], rows))
    print(f"{port}: {len(servos)} servo(s) at {scanned} baud ({elapsed_s:.1f} s)")
    return 0
