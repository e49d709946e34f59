"""`rig sim servos`: serve emulated Dynamixel servos (Protocol 2.0, or 1.0) on a pty until killed.

Also runnable as `python -m rig.cli.sim_servos ...` with the same arguments (used by the test
fixture, so that it does not depend on every other command importing).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rig.errors import InputError, one_line
from rig.hw.clock import SystemClock
from rig.hw.dxl.control_table import BAUD_REGISTER_BY_RATE, MODELS
from rig.sim.dxl.bus import EmulatedBus
from rig.sim.dxl.faults import FaultSpec, parse_fault
from rig.sim.dxl.protocol1 import Protocol1Bus
from rig.sim.dxl.pty_server import ServedBus, serve
from rig.sim.pty_link import PtyLink, StopFlag


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig sim servos`."""
    parser = subparsers.add_parser(
        "servos",
        help="serve emulated Dynamixel servos on a pty",
        description=(
            "Serve emulated Dynamixel X-series servos (Protocol 2.0, byte for byte) on a pseudo-terminal "
            "symlinked at --link, in real time, until killed (SIGTERM/SIGINT exit 0 and remove the link). "
            "Prints one line `PTY <device> LINK <link>` when ready. Servos stay silent when the client's "
            "baud rate differs from theirs."
        ),
    )
    add_arguments(parser)
    parser.set_defaults(handler=run)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of `rig sim servos`."""
    parser.add_argument("--ids", default="1", help="comma-separated servo IDs, 0-252 (default 1)")
    parser.add_argument(
        "--model", default="XM430-W350", help=f"servo model: {', '.join(MODELS)} (default XM430-W350)"
    )
    parser.add_argument("--baud", type=int, default=1_000_000, help="servo baud rate (default 1000000)")
    parser.add_argument("--link", required=True, help="path of the symlink to create (e.g. /tmp/dxl)")
    parser.add_argument("--firmware", type=int, default=None, help="firmware version to report (default 48)")
    parser.add_argument(
        "--protocol",
        choices=("2.0", "1.0"),
        default="2.0",
        help="the protocol the servos answer: 1.0 as an X-series servo switched to it (Protocol Type 1)",
    )
    parser.add_argument(
        "--wire-timing",
        action="store_true",
        help="hold each reply until its simulated wire time (default: reply as soon as computed)",
    )
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="SPEC",
        help=(
            "inject a fault (repeatable): drop:N[:ID], corrupt:N[:ID], delay:N:MS[:ID], silent:ID, "
            "hwerror:ID:BITS, baud:ID:RATE"
        ),
    )


def parse_ids(text: str) -> list[int]:
    """'1,2,3' -> [1, 2, 3]; InputError for anything else."""
    ids: list[int] = []
    for part in text.split(","):
        try:
            value = int(part.strip())
        except ValueError:
            raise InputError(f"--ids {text}: {part.strip()!r} is not an integer; allowed: 0..252") from None
        if not 0 <= value <= 252:
            raise InputError(f"--ids {text}: {value} out of range; allowed: 0..252")
        if value in ids:
            raise InputError(f"--ids {text}: {value} appears twice; IDs must be unique")
        ids.append(value)
    return ids


def build_bus(args: argparse.Namespace) -> tuple[EmulatedBus, list[FaultSpec]]:
    """Validate the arguments and make the bus with its faults applied."""
    ids = parse_ids(args.ids)
    if args.model not in MODELS:
        raise InputError(f"--model {args.model}: unknown model; allowed: {', '.join(MODELS)}")
    if args.baud not in BAUD_REGISTER_BY_RATE:
        allowed = ", ".join(str(r) for r in BAUD_REGISTER_BY_RATE)
        raise InputError(f"--baud {args.baud}: not a Dynamixel baud rate; allowed: {allowed}")
    if args.firmware is not None and not 0 <= args.firmware <= 255:
        raise InputError(f"--firmware {args.firmware}: out of range; allowed: 0..255")
    specs = [parse_fault(s) for s in args.fault]
    kwargs = {} if args.firmware is None else {"firmware": args.firmware}
    bus = EmulatedBus.with_servos(SystemClock(), ids=ids, model=args.model, baud=args.baud, **kwargs)
    for spec in specs:
        if (
            spec.servo_id is not None
            and spec.servo_id not in ids
            and spec.kind in ("silent", "hwerror", "baud")
        ):
            raise InputError(
                f"--fault {spec.kind}:{spec.servo_id}...: no servo {spec.servo_id}; ids: {args.ids}"
            )
        if spec.kind == "drop":
            bus.faults.drop_next(spec.count, spec.servo_id)
        elif spec.kind == "corrupt":
            bus.faults.corrupt_next(spec.count, spec.servo_id)
        elif spec.kind == "delay":
            bus.faults.delay_next(spec.count, spec.delay_ms / 1000.0, spec.servo_id)
        elif spec.kind == "silent":
            bus.set_silent(spec.servo_id)  # type: ignore[arg-type]
        elif spec.kind == "hwerror":
            bus.set_hardware_error(spec.servo_id, spec.bits)  # type: ignore[arg-type]
        elif spec.kind == "baud":
            bus.servo(spec.servo_id).set_baud(spec.baud)  # type: ignore[arg-type]
    return bus, specs


def run(args: argparse.Namespace) -> int:
    """Serve until SIGTERM/SIGINT; returns 0."""
    bus, _ = build_bus(args)
    served: ServedBus = bus
    if getattr(args, "protocol", "2.0") == "1.0":
        served = Protocol1Bus(bus.servos, baud=bus.baud)
    stop = StopFlag()
    with PtyLink.for_cli(args.link) as link:
        print(f"PTY {link.slave_name} LINK {link.link_path}", flush=True)
        stats = serve(served, link, stop, wire_timing=args.wire_timing)
    print(
        f"stopped: {stats.bytes_in} bytes in, {stats.replies} replies ({stats.bytes_out} bytes) out, "
        f"{bus.crc_errors} CRC errors",
        file=sys.stderr,
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry point (`python -m rig.cli.sim_servos`), same arguments and exit codes."""
    parser = argparse.ArgumentParser(prog="rig sim servos")
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run(args)
    except InputError as exc:
        print(f"rig: error: {one_line(str(exc))}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
