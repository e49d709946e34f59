"""`rig scan --port PORT`: find the Dynamixel servos on a port (Protocol 2.0 and 1.0) at each baud rate."""

from __future__ import annotations

import argparse
import os
import time

from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.errors import InputError
from rig.hw.dxl.control_table import SDK_BAUDS
from rig.hw.dxl.discovery import scan_port
from rig.hw.dxl.setup import SETTABLE_BAUDS

DEFAULT_BAUDS = (57_600, 1_000_000)
DEFAULT_PROTOCOL1_MAX_ID = 31

DESCRIPTION = """\
Broadcast-ping the Dynamixel bus (Protocol 2.0) on PORT at each --baud and list every servo that
answers with its ID, model and firmware version. dynamixel-sdk waits its whole broadcast window
whatever answers, so each baud rate takes about a second (0.8 s at 1 Mbps, 1.4 s at 57600).

Then look for Protocol 1.0 servos (an X-series servo switched to 1.0, an MX on its 1.0 firmware,
an AX), which a 2.0 ping does not reach: 1.0 has no broadcast ping that answers, so IDs
0..--protocol1-max-id are pinged one by one at each baud (about 35 ms per silent ID). Each one
found is named with how to switch it to Protocol 2.0, which the rig speaks.
"""

EPILOG = """\
JSON (--json): {"port": PORT, "servos": [{"id", "model_number", "model", "firmware", "baud",
"protocol": 2.0 or 1.0, "switch": how to switch a 1.0 servo to 2.0 (1.0 servos only)}, ...]}.
When nothing answers, the text output says where else to look (the servo supply, the U2D2 port,
the baud rates not scanned, Protocol 1.0 IDs beyond --protocol1-max-id).
Exit codes: 0 done (also when nothing answered); 1 the port could not be used; 2 invalid input
(e.g. the port does not exist, or a baud rate the SDK cannot set).
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig scan`."""
    parser = subparsers.add_parser(
        "scan",
        help=COMMANDS["scan"],
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
        "--protocol1-max-id",
        type=int,
        default=DEFAULT_PROTOCOL1_MAX_ID,
        metavar="N",
        help=f"ping IDs 0..N with Protocol 1.0 at each baud (0-252; default {DEFAULT_PROTOCOL1_MAX_ID}; "
        "-1 skips the Protocol 1.0 search)",
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
    max_id = args.protocol1_max_id
    if not -1 <= max_id <= 252:
        raise InputError(f"--protocol1-max-id {max_id}: out of range; allowed: -1 (skip) or 0..252")
    started = time.monotonic()
    servos = scan_port(port, bauds, protocol1_ids=range(max_id + 1))
    elapsed_s = time.monotonic() - started
    if args.json:
        servo_records = [
            {
                "id": s.servo_id,
                "model_number": s.model_number,
                "model": s.model,
                "firmware": s.firmware,
                "baud": s.baud,
                "protocol": s.protocol,
                **({"switch": s.switch_advice} if s.protocol == 1.0 else {}),
            }
            for s in servos
        ]
        emit_json({"port": port, "servos": servo_records})
        return 0
    scanned = ", ".join(str(b) for b in bauds)
    if not servos:
        print(f"{port}: no servos answered at {scanned} baud ({elapsed_s:.1f} s)")
        for hint in _nothing_answered_hints(bauds, max_id):
            print(f"  - {hint}")
        return 0
    rows = [[s.servo_id, s.model, s.model_number, s.firmware, s.baud, f"{s.protocol:.1f}"] for s in servos]
    print(format_table(["id", "model", "model number", "firmware", "baud", "protocol"], rows))
    print(f"{port}: {len(servos)} servo(s) at {scanned} baud ({elapsed_s:.1f} s)")
    for s in servos:
        if s.protocol == 1.0:
            print(
                f"servo {s.servo_id} ({s.model}) answers Protocol 1.0, which the rig does not speak: "
                + s.switch_advice
            )
    return 0


def _nothing_answered_hints(bauds: tuple[int, ...], protocol1_max_id: int) -> list[str]:
    """Where else a servo that did not answer may be: power, the other rates, higher Protocol 1.0 IDs."""
    hints = [
        "is the servo supply on? The U2D2 does not power the servos, and the e-stop cuts their supply",
        "is the cable on the U2D2 port that matches the servos: TTL (3-pin) for X-series -T models, "
        "RS-485 (4-pin) for -R models (ROBOTIS e-manual, U2D2)?",
    ]
    others = [b for b in SETTABLE_BAUDS if b not in bauds]
    if others:
        hints.append(
            "a servo set to another baud rate: scan those too, " + " ".join(f"--baud {b}" for b in others)
        )
    if protocol1_max_id < 252:
        searched = f"IDs 0-{protocol1_max_id}" if protocol1_max_id >= 0 else "no IDs"
        hints.append(
            f"a Protocol 1.0 servo was searched at {searched}: --protocol1-max-id 252 searches every ID "
            "(about 35 ms per ID and baud)"
        )
    return hints
