"""`rig sim servos`: serve emulated Dynamixel servos (Protocol 2.0, or 1.0) on a pty until killed.

Also runnable as `python -m rig.cli.sim_servos ...` with the same arguments (used by the test
fixture, so that it does not depend on every other command importing).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import assert_never

from rig.errors import InputError, one_line
from rig.hw.clock import SystemClock
from rig.hw.dxl.control_table import BAUD_REGISTER_BY_RATE, MODELS
from rig.sim.dxl.bus_pty_server import ServedBus, serve
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.dxl.faults import FaultSpec, parse_fault
from rig.sim.dxl.packet1 import Protocol1Bus
from rig.sim.kinds import ServoFaultFlag
from rig.sim.pty_port import PtyPort, StopFlag


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
        "--model",
        default="XM430-W350",
        help=f"servo model, or comma-separated models one per --ids entry for a mixed bus (e.g. "
        f"--ids 1,2,3 --model XM430-W350,XM430-W350,XM430-W210): {', '.join(MODELS)} (default XM430-W350)",
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
        "--usb-latency-ms",
        type=float,
        default=0.0,
        help="hold every reply this long, as a USB-serial adapter's latency timer does (Linux's FTDI "
        "default 16, set to 1 by the udev rule in docs/udev/99-rig.rules); default 0",
    )
    parser.add_argument(
        "--sysfs-root",
        default=None,
        metavar="DIR",
        help="with --usb-latency-ms: also write DIR/bus/usb-serial/devices/<pty>/latency_timer, where "
        "`rig check --sysfs-root DIR` reads it as it reads /sys for a real adapter",
    )
    parser.add_argument(
        "--voltage-v", type=float, default=None, help="Present Input Voltage to report, V (default 12.0)"
    )
    parser.add_argument(
        "--temperature-c", type=int, default=None, help="Present Temperature to report, degC (default 30)"
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


def parse_models(text: str, ids: Sequence[int]) -> list[str]:
    """'M' (every servo) or 'M1,M2,...' (one per ID) -> a model per ID; InputError otherwise."""
    models = [m.strip() for m in text.split(",")]
    for model in models:
        if model not in MODELS:
            which = "" if len(models) == 1 else f" {model!r}"
            raise InputError(f"--model {text}: unknown model{which}; allowed: {', '.join(MODELS)}")
    if len(models) == 1:
        return models * len(ids)
    if len(models) != len(ids):
        raise InputError(
            f"--model {text}: {len(models)} models for {len(ids)} --ids; allowed: one model, or one per ID"
        )
    return models


def build_bus(args: argparse.Namespace) -> tuple[EmulatedBus, list[FaultSpec]]:
    """Validate the arguments and make the bus with its faults applied."""
    ids = parse_ids(args.ids)
    models = parse_models(args.model, ids)
    if args.baud not in BAUD_REGISTER_BY_RATE:
        allowed = ", ".join(str(r) for r in BAUD_REGISTER_BY_RATE)
        raise InputError(f"--baud {args.baud}: not a Dynamixel baud rate; allowed: {allowed}")
    if args.firmware is not None and not 0 <= args.firmware <= 255:
        raise InputError(f"--firmware {args.firmware}: out of range; allowed: 0..255")
    if not 0 <= args.usb_latency_ms <= 255:  # the FTDI latency timer's range, 1-255 ms (0: none)
        raise InputError(f"--usb-latency-ms {args.usb_latency_ms}: allowed: 0 to 255")
    if args.voltage_v is not None and not 0 <= args.voltage_v <= 6553.5:
        raise InputError(f"--voltage-v {args.voltage_v}: allowed: 0 to 6553.5")
    if args.temperature_c is not None and not 0 <= args.temperature_c <= 255:
        raise InputError(f"--temperature-c {args.temperature_c}: allowed: 0 to 255")
    specs = [parse_fault(s) for s in args.fault]
    kwargs = {} if args.firmware is None else {"firmware": args.firmware}
    bus = EmulatedBus.with_servos(SystemClock(), ids=ids, model=models, baud=args.baud, **kwargs)
    for servo in bus.servos:
        if args.voltage_v is not None:
            servo.supply_voltage_v = args.voltage_v
        if args.temperature_c is not None:
            servo.set_temperature_c(args.temperature_c)
    for spec in specs:
        if (
            spec.servo_id is not None
            and spec.servo_id not in ids
            and spec.kind in (ServoFaultFlag.SILENT, ServoFaultFlag.HWERROR, ServoFaultFlag.BAUD)
        ):
            raise InputError(
                f"--fault {spec.kind}:{spec.servo_id}...: no servo {spec.servo_id}; ids: {args.ids}"
            )
        match spec.kind:
            case ServoFaultFlag.DROP:
                bus.faults.drop_next(spec.count, spec.servo_id)
            case ServoFaultFlag.CORRUPT:
                bus.faults.corrupt_next(spec.count, spec.servo_id)
            case ServoFaultFlag.DELAY:
                bus.faults.delay_next(spec.count, spec.delay_ms / 1000.0, spec.servo_id)
            case ServoFaultFlag.SILENT:
                bus.set_silent(spec.servo_id)  # type: ignore[arg-type]
            case ServoFaultFlag.HWERROR:
                bus.set_hardware_error(spec.servo_id, spec.bits)  # type: ignore[arg-type]
            case ServoFaultFlag.BAUD:
                bus.servo(spec.servo_id).set_baud(spec.baud)  # type: ignore[arg-type]
            case _:
                assert_never(spec.kind)
    return bus, specs


def run(args: argparse.Namespace) -> int:
    """Serve until SIGTERM/SIGINT; returns 0."""
    bus, _ = build_bus(args)
    served: ServedBus = bus
    if getattr(args, "protocol", "2.0") == "1.0":
        served = Protocol1Bus(bus.servos, baud=bus.baud)
    stop = StopFlag()
    with PtyPort.for_cli(args.link) as link:
        latency_file = _write_latency_timer(args, link.slave_name)
        print(f"PTY {link.slave_name} LINK {link.link_path}", flush=True)
        try:
            latency_s: float | Callable[[], float] = args.usb_latency_ms / 1e3
            if latency_file is not None:
                latency_s = LatencyTimerFile(latency_file, args.usb_latency_ms / 1e3)
            stats = serve(served, link, stop, wire_timing=args.wire_timing, usb_latency_s=latency_s)
        finally:
            if latency_file is not None:
                latency_file.unlink(missing_ok=True)
    print(
        f"stopped: {stats.bytes_in} bytes in, {stats.replies} replies ({stats.bytes_out} bytes) out, "
        f"{bus.crc_errors} CRC errors",
        file=sys.stderr,
    )
    return 0


class LatencyTimerFile:
    """The emulated adapter's latency timer as its sysfs file says now (re-read at most every 0.2 s).

    A real FTDI adapter takes a new value written to its `latency_timer` file at once (the udev rule
    in docs/udev/99-rig.rules writes 1); the emulator follows its own file the same way. A file
    that cannot be read or parsed leaves the last value.
    """

    REREAD_S = 0.2

    def __init__(self, path: Path, initial_s: float) -> None:
        self.path = path
        self.value_s = initial_s
        self._read_at = time.monotonic()

    def __call__(self) -> float:
        now = time.monotonic()
        if now - self._read_at >= self.REREAD_S:
            self._read_at = now
            try:
                ms = int(self.path.read_text().strip())
            except (OSError, ValueError):
                return self.value_s
            if 0 <= ms <= 255:
                self.value_s = ms / 1e3
        return self.value_s


def _write_latency_timer(args: argparse.Namespace, device: str) -> Path | None:
    """With --sysfs-root: the emulated adapter's latency timer where `rig check` looks for it."""
    if args.sysfs_root is None:
        return None
    path = Path(args.sysfs_root) / "bus" / "usb-serial" / "devices" / Path(device).name / "latency_timer"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{round(args.usb_latency_ms)}\n")
    except OSError as exc:
        raise InputError(f"--sysfs-root {args.sysfs_root}: cannot write {path} ({exc.strerror})") from None
    return path


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
