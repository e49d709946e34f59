"""`rig sim loadcell`: serve an emulated serial load cell on a pty until killed."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from rig.errors import InputError
from rig.hw.loadcell.formats import FORMATS
from rig.sim.loadcell.emulator import (
    DEFAULT_BAUD,
    DEFAULT_RATE_HZ,
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    FaultPlan,
    LoadCellEmulator,
    SignalModel,
    firmware_banner,
    parse_fault,
)
from rig.sim.loadcell.inprocess_line import cell_emulator_options
from rig.sim.loadcell.line_pty_server import serve_loadcell
from rig.sim.loadcell.profiles import parse_profile
from rig.sim.pty_port import PtyPort, StopFlag
from rig.sim.settings import SIMULATED_CELLS

MAX_SEED = 2**64 - 1


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig sim loadcell`."""
    defaults = SignalModel()
    parser = subparsers.add_parser(
        "loadcell",
        help="serve an emulated serial load cell on a pty",
        description=(
            "Stream load-cell lines on a pseudo-terminal symlinked at --link, in real time, until "
            "killed (SIGTERM/SIGINT exit 0 and remove the link). Prints one line `PTY <link> <device> ...` "
            "when ready. Formats are specified in protocols/loadcell-formats.md. Without a simulated "
            "world the tension follows --profile."
        ),
    )
    parser.add_argument("--link", required=True, help="path of the symlink to create (e.g. /tmp/loadcell)")
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        help="samples per second, 10-2000, or a polled format's most polls per second (default 1000)",
    )
    parser.add_argument(
        "--format", default=None, choices=sorted(FORMATS), help="line format (default rig-lc1)"
    )
    parser.add_argument(
        "--baud", type=int, default=DEFAULT_BAUD, help=f"device baud rate (default {DEFAULT_BAUD})"
    )
    parser.add_argument(
        "--profile",
        default="sawtooth",
        help="tension profile: constant:TENSION_N or sawtooth[:PEAK_N[:PERIOD_S]] (default sawtooth:20:4)",
    )
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="SPEC",
        help=(
            "inject faults (repeatable): garbage|truncate|checksum|gap:PROBABILITY_PER_LINE, or "
            "silence:START_S:DURATION_S (seconds after start)"
        ),
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed for noise and faults (default 0)")
    parser.add_argument(
        "--gain-counts-per-n",
        type=float,
        default=defaults.gain_counts_per_n,
        help=f"ADC counts per newton (default {defaults.gain_counts_per_n:g})",
    )
    parser.add_argument(
        "--offset-counts",
        type=float,
        default=defaults.offset_counts,
        help=f"counts at zero tension (default {defaults.offset_counts:g})",
    )
    parser.add_argument(
        "--noise-counts",
        type=float,
        default=defaults.noise_counts,
        help=f"RMS Gaussian noise in counts (default {defaults.noise_counts:g})",
    )
    parser.add_argument(
        "--drift-counts-per-s",
        type=float,
        default=defaults.drift_counts_per_s,
        help=f"zero drift in counts per second (default {defaults.drift_counts_per_s:g})",
    )
    parser.add_argument(
        "--cell",
        choices=[name for name, cell in SIMULATED_CELLS.items() if cell is not None],
        default=None,
        help="emulate a cell labs own (its rate, format, counts, noise, settling and banner; "
        "protocols/README.md); --rate and --format must then be left out or agree with it",
    )
    parser.add_argument(
        "--clock-error-ppm",
        type=float,
        default=0.0,
        help="the device clock runs this fast, in ppm (negative: slow; default 0)",
    )
    parser.add_argument(
        "--dtr-reset-s",
        type=float,
        default=0.0,
        help="the board resets when a client opens the port (an Arduino's DTR): silent this long, then "
        "its banner, seq and clock from 0 (Linux: the open is seen with inotify; default 0: no reset)",
    )
    parser.add_argument(
        "--banner",
        action="store_true",
        help="rig-lc1: send a boot banner (`#BOOT fw=rig-sim/1.0.0 adc=emulated gain=A128 sps=RATE "
        "period-us=PERIOD`) before the first line, as firmware/ does",
    )
    parser.set_defaults(handler=run)


def build_emulator(args: argparse.Namespace, start_ns: int) -> LoadCellEmulator:
    """Validate the arguments and make the emulator (no pty yet); InputError for a bad option."""
    if not 0 <= args.seed <= MAX_SEED:
        raise InputError(f"--seed {args.seed}: allowed: an integer from 0 to {MAX_SEED}")
    plan = FaultPlan()
    for spec in args.fault:
        plan = parse_fault(spec, plan)
    options: dict[str, Any] = {
        "signal": SignalModel(
            gain_counts_per_n=args.gain_counts_per_n,
            offset_counts=args.offset_counts,
            drift_counts_per_s=args.drift_counts_per_s,
            noise_counts=args.noise_counts,
        ),
    }
    cell = SIMULATED_CELLS[args.cell] if args.cell else None
    if cell is not None:
        for flag, given, own in (("--rate", args.rate, cell.rate_hz), ("--format", args.format, cell.format)):
            if given is not None and given != own:
                raise InputError(f"{flag} {given}; allowed: {own} with --cell {args.cell} (or leave it out)")
        args.rate, args.format = cell.rate_hz, cell.format
        options = cell_emulator_options(cell)
    args.rate = DEFAULT_RATE_HZ if args.rate is None else args.rate
    args.format = args.format or "rig-lc1"
    if cell is None and args.banner and MIN_RATE_HZ <= args.rate <= MAX_RATE_HZ:  # (else the rate is refused)
        options["banner"] = firmware_banner(args.rate)
    return LoadCellEmulator(
        parse_profile(args.profile, start_ns),
        format_name=args.format,
        rate_hz=args.rate,
        baud=args.baud,
        faults=plan,
        seed=args.seed,
        start_ns=start_ns,
        clock_error_ppm=args.clock_error_ppm,
        dtr_reset_s=args.dtr_reset_s,
        **options,
    )


def run(args: argparse.Namespace) -> int:
    """Serve until SIGTERM/SIGINT; returns 0."""
    emulator = build_emulator(args, time.monotonic_ns())
    stop = StopFlag()
    with PtyPort.for_cli(args.link) as link:
        print(
            f"PTY {link.link_path} {link.slave_name} loadcell format={args.format} rate={args.rate:g}Hz "
            f"baud={args.baud}",
            flush=True,
        )
        counts = serve_loadcell(emulator, link, stop)
    print(
        f"stopped: {counts.lines_written} lines, {counts.bytes_written} bytes written, "
        f"{counts.bytes_dropped} dropped (nobody reading)",
        file=sys.stderr,
    )
    return 0
