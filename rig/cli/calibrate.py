"""`rig calibrate`: walk an operator through tare and a reference mass, then write the calibration JSON."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.errors import InputError
from rig.hw.clock import SystemClock
from rig.hw.loadcell.calibration import (
    REFERENCE_MASS_RANGE_KG,
    TEMPERATURE_RANGE_C,
    Calibration,
    CalibrationError,
    CalibrationStep,
    run_calibration,
)
from rig.hw.loadcell.driver import DEFAULT_BAUD, DEFAULT_STALE_TIMEOUT_S, SerialLoadCell
from rig.hw.loadcell.formats import FORMATS
from rig.hw.seams import Clock, LoadCell
from rig.sim.settings import load_checked_rig_config
from rig.vocabulary import LOADCELL_FORMAT_TRAITS, LoadCellFormatName, RigKind

PromptFn = Callable[[CalibrationStep, str], None]
DEFAULT_POLL_RATE_HZ = 12.0  # a force gauge's display rate (issue 21: 10-12/s)


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig calibrate`."""
    parser = subparsers.add_parser(
        "calibrate",
        help=COMMANDS["calibrate"],
        description=(
            "Calibrate the line load cell: with no load, the mean raw count is the offset (tare); "
            "with a known tension in the line, factor = mass * g / (raw_ref - raw_zero). The cell sits "
            "inline, so the reference is a tension through it: a mass hanging from the line (over the "
            "pulley, the cell in the line as in a trial), or a pull read on a reference gauge given as "
            "--reference-kg = newtons / g. Prompts the operator before each step, then writes --out "
            "atomically (Ctrl-C leaves no file). --sim runs against the in-process simulated load cell, "
            "where the simulation applies the load."
        ),
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--port", help="serial port or pyserial URL of the load cell (e.g. /dev/ttyUSB0)")
    source.add_argument("--sim", action="store_true", help="use the in-process simulated load cell")
    source.add_argument(
        "--rig",
        type=Path,
        metavar="CONFIG",
        help="take port, baud, format (and --out: loadcell.calibration) from a hardware rig config",
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=None,
        help=f"baud rate (default {DEFAULT_BAUD}; with --sim, the emulator's default)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        help="samples per second the cell sends, or the poll rate of a polled format such as value-unit "
        f"(default: none for a streaming cell, {DEFAULT_POLL_RATE_HZ:g} for a polled one; with --sim, "
        "the emulator's default for a streaming cell)",
    )
    parser.add_argument(
        "--format", default="rig-lc1", choices=sorted(FORMATS), help="line format (default rig-lc1)"
    )
    parser.add_argument(
        "--reference-kg",
        type=float,
        required=True,
        help="the reference tension as a mass in kg: the hanging mass, or a gauge's newtons / g",
    )
    parser.add_argument(
        "--out", default=None, help="calibration JSON file to write (required unless --rig names one)"
    )
    parser.add_argument(
        "--settle-s",
        type=float,
        default=2.0,
        help="wait after each confirmation before averaging (default 2)",
    )
    parser.add_argument("--average-s", type=float, default=1.0, help="averaging window in s (default 1)")
    parser.add_argument(
        "--g",
        type=float,
        default=STANDARD_GRAVITY_M_S2,
        help=f"local gravity in m/s^2 (default {STANDARD_GRAVITY_M_S2})",
    )
    parser.add_argument("--serial", default="", help="load cell serial number, stored in the file")
    parser.add_argument(
        "--temperature-c", type=float, default=None, help="ambient temperature, stored in the file"
    )
    parser.add_argument(
        "--stale-timeout-s",
        type=float,
        default=DEFAULT_STALE_TIMEOUT_S,
        help=f"fail when no sample arrives for this long (default {DEFAULT_STALE_TIMEOUT_S:g})",
    )
    parser.add_argument("--seed", type=int, default=0, help="with --sim: random seed (default 0)")
    parser.add_argument("--yes", action="store_true", help="do not wait for confirmations")
    parser.add_argument(
        "--force",
        action="store_true",
        help="overwrite an existing calibration file without asking (without it: asked at a terminal, "
        "refused otherwise)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    parser.set_defaults(handler=run)


def apply_rig_config(args: argparse.Namespace) -> None:
    """With --rig, fill the load-cell port, baud, format and output file from the rig config."""
    if getattr(args, "rig", None) is None:
        return
    config = load_checked_rig_config(args.rig)
    if config.kind != RigKind.HARDWARE:
        raise InputError(f"{args.rig}: kind: {config.kind}; --rig needs a hardware rig (use --sim to try it)")
    args.port = config.loadcell.port
    args.baud = config.loadcell.baud
    args.rate = config.loadcell.rate_hz
    args.format = config.loadcell.format
    if args.out is None:
        if config.loadcell.calibration_path is None:
            raise InputError(f"{args.rig}: loadcell.calibration is not set; give --out")
        args.out = str(config.loadcell.calibration_path)


def validate_args(args: argparse.Namespace) -> None:
    """Reject impossible values before touching any hardware."""
    apply_rig_config(args)
    if args.baud is None:
        args.baud = DEFAULT_BAUD
        if args.sim:  # imported here: only --sim needs the simulator
            from rig.sim.loadcell.emulator import DEFAULT_BAUD as SIM_BAUD

            args.baud = SIM_BAUD
    polled = LOADCELL_FORMAT_TRAITS[LoadCellFormatName(args.format)].poll_command is not None
    if args.rate is None and polled:
        args.rate = DEFAULT_POLL_RATE_HZ
    if args.rate is not None and not 1 <= args.rate <= 2000:
        raise InputError(f"--rate {args.rate}; allowed: 1-2000 samples (or polls) per second")
    if args.out is None:
        raise InputError("--out: required (the calibration JSON file to write)")
    lo_kg, hi_kg = REFERENCE_MASS_RANGE_KG  # what a calibration file may hold (docs/formats.md §6)
    lo_c, hi_c = TEMPERATURE_RANGE_C
    temperature = 20.0 if args.temperature_c is None else args.temperature_c
    checks = [
        (
            "--reference-kg",
            args.reference_kg,
            lo_kg <= args.reference_kg <= hi_kg,
            f"> 0 ({lo_kg:g} to {hi_kg:g})",
        ),
        ("--settle-s", args.settle_s, 0 <= args.settle_s <= 600, "0-600"),
        ("--average-s", args.average_s, 0.01 <= args.average_s <= 600, "> 0 (0.01 to 600)"),
        ("--g", args.g, 9.7 <= args.g <= 9.9, "9.7-9.9 (Earth's surface)"),
        ("--stale-timeout-s", args.stale_timeout_s, 0.005 <= args.stale_timeout_s <= 10, "> 0 (0.005 to 10)"),
        ("--temperature-c", args.temperature_c, lo_c <= temperature <= hi_c, f"{lo_c:g} to {hi_c:g}"),
    ]
    for flag, value, ok, allowed in checks:
        if not ok:  # NaN fails every comparison
            raise InputError(f"{flag} {value}; allowed: {allowed}")
    if len(args.serial) > 256 or not args.serial.isprintable():
        raise InputError(f"--serial {args.serial!r:.70}: allowed: printable text of at most 256 characters")
    out = Path(args.out)
    if out.is_dir():
        raise InputError(f"--out {out}: is a directory; allowed: a file path")
    if out.exists() and not args.force:
        _confirm_overwrite(out, ask=sys.stdin is not None and sys.stdin.isatty() and not args.json)


def _confirm_overwrite(out: Path, *, ask: bool) -> None:
    """Keep an existing calibration unless the operator says to replace it (at a terminal only)."""
    if ask:
        try:
            answer = input(f"{out} holds a calibration already; overwrite it with the new one? [y/N] ")
        except EOFError:
            answer = ""
        if answer.strip().lower() in ("y", "yes"):
            return
    raise InputError(
        f"--out {out}: a calibration exists there and was kept; --force overwrites it, or give another --out"
    )


def operator_prompt(auto_confirm: bool, log: Callable[[str], None]) -> PromptFn:
    """Prompt on the terminal and wait for Enter, or only log the prompt when auto-confirming."""

    def prompt(step: CalibrationStep, message: str) -> None:
        if auto_confirm:
            log(f"{message} [auto-confirmed]")
            return
        try:
            input(f"{message}\nPress Enter when ready (Ctrl-C aborts, nothing is written): ")
        except EOFError:
            raise CalibrationError(
                "stdin closed before the operator confirmed; use --yes to auto-confirm"
            ) from None

    return prompt


def run(args: argparse.Namespace) -> int:
    """Run the calibration and write the file; returns the exit code."""
    validate_args(args)

    def log(message: str) -> None:
        print(message, file=sys.stderr if args.json else sys.stdout, flush=True)

    auto_confirm = args.yes or (args.sim and not sys.stdin.isatty())
    prompt = operator_prompt(auto_confirm, log)
    clock: Clock
    load_cell: LoadCell
    if args.sim:
        load_cell, clock, prompt = _simulated(args, prompt)
        port = "sim"
    else:
        clock = SystemClock()
        load_cell = SerialLoadCell(
            args.port,
            baud=args.baud,
            format_name=args.format,
            stale_timeout_s=args.stale_timeout_s,
            clock=clock,
            rate_hz=args.rate,
        )
        port = args.port
    log(f"load cell on {port} ({args.format}); reference {args.reference_kg:g} kg, g = {args.g:g} m/s^2")
    load_cell.open()
    try:
        calibration = run_calibration(
            load_cell,
            prompt,
            args.reference_kg,
            args.settle_s,
            clock=clock,
            average_s=args.average_s,
            g=args.g,
            serial=args.serial,
            format_name=args.format,
            temperature_c=args.temperature_c,
            progress_fn=log,
        )
    finally:
        load_cell.close()
    calibration.save(args.out)
    _report(args, calibration)
    return 0


def _report(args: argparse.Namespace, calibration: Calibration) -> None:
    noise_n = calibration.noise_n
    if args.json:
        emit_json({"out": str(args.out), **calibration.to_dict(), "noise_n": noise_n})
        return
    rows = [
        ("factor", f"{calibration.factor_n_per_count:.6e}", "N/count"),
        ("offset", f"{calibration.offset_counts:.1f}", "counts"),
        ("noise at zero", f"{noise_n:.4g}" if noise_n is not None else "-", "N RMS"),
        ("reference", f"{args.reference_kg:g} kg = {args.reference_kg * args.g:.4g}", "N"),
    ]
    print(format_table(["quantity", "value", "unit"], rows))
    print(f"wrote {args.out}")


def _simulated(args: argparse.Namespace, prompt: PromptFn) -> tuple[LoadCell, Clock, PromptFn]:
    """The in-process emulator on a virtual clock; the prompts move the simulated mass."""
    from rig.sim.loadcell.emulator import DEFAULT_RATE_HZ, LoadCellEmulator
    from rig.sim.loadcell.inprocess_line import SIM_PORT, in_process_serial_factory
    from rig.sim.loadcell.profiles import StepTension
    from rig.sim.virtual_clock import VirtualClock

    clock = VirtualClock()
    # The line starts with an unknown load on it: the operator has to take it off for the tare.
    tension = StepTension(0.8)
    emulator = LoadCellEmulator(
        tension,
        format_name=args.format,
        rate_hz=args.rate or DEFAULT_RATE_HZ,
        baud=args.baud,
        seed=args.seed,
        start_ns=clock.monotonic_ns(),
    )
    load_cell = SerialLoadCell(
        SIM_PORT,
        baud=args.baud,
        format_name=args.format,
        stale_timeout_s=args.stale_timeout_s,
        clock=clock,
        serial_factory=in_process_serial_factory(emulator, clock),
        rate_hz=args.rate,
    )

    def sim_prompt(step: CalibrationStep, message: str) -> None:
        prompt(step, message)
        target_n = 0.0 if step is CalibrationStep.REMOVE_LOAD else args.reference_kg * args.g
        tension.set(target_n, clock.monotonic_ns())

    return load_cell, clock, sim_prompt
