"""`rig sim loadcell`: serve an emulated serial load cell on a pty until killed."""

from __future__ import annotations

import argparse
import sys
import time

from rig.errors import InputError
from rig.hw.loadcell.formats import FORMATS
from rig.sim.loadcell.emulator import (
    DEFAULT_BANNER,
    DEFAULT_BAUD,
    FaultPlan,
    LoadCellEmulator,
    SignalModel,
    parse_fault,
)
from rig.sim.loadcell.profiles import parse_profile
from rig.sim.loadcell.pty_server import serve_loadcell
from rig.sim.pty_link import PtyLink, StopFlag

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
        "--rate", type=float, default=1000.0, help="samples per second, 10-2000 (default 1000)"
    )
    parser.add_argument(
        "--format", default="rig-lc1", choices=sorted(FORMATS), help="line format (default rig-lc1)"
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
        "--banner",
        action="store_true",
        help=f"rig-lc1: send a boot banner ({DEFAULT_BANNER.decode().strip()}) before the first line, "
        "as firmware/ does",
    )
    parser.set_defaults(handler=run)


def build_emulator(args: argparse.Namespace, start_ns: int) -> LoadCellEmulator:
    """Validate the arguments and make the emulator (no pty yet); InputError for a bad option."""
    if not 0 <= args.seed <= MAX_SEED:
        raise InputError(f"--seed {args.seed}: allowed: an integer from 0 to {MAX_SEED}")
    plan = FaultPlan()
    for spec in args.fault:
        plan = parse_fault(spec, plan)
    return LoadCellEmulator(
        parse_profile(args.profile, start_ns),
        format_name=args.format,
        rate_hz=args.rate,
        baud=args.baud,
        signal=SignalModel(
            gain_counts_per_n=args.gain_counts_per_n,
            offset_counts=args.offset_counts,
            drift_counts_per_s=args.drift_counts_per_s,
            noise_counts=args.noise_counts,
        ),
        faults=plan,
        seed=args.seed,
        start_ns=start_ns,
        banner=DEFAULT_BANNER if args.banner else None,
    )


def run(args: argparse.Namespace) -> int:
    """Serve until SIGTERM/SIGINT; returns 0."""
    emulator = build_emulator(args, time.monotonic_ns())
    stop = StopFlag()
    with PtyLink.for_cli(args.link) as link:
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
