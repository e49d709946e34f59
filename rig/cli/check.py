"""`rig check`: the pre-flight check of a rig, one row per check (pass, warn, fail) with the fix."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json
from rig.errors import ExitCode, InputError
from rig.hw.usb_latency import DEFAULT_SYSFS_ROOT
from rig.safety.interrupts import interrupts_deferred

if TYPE_CHECKING:
    from rig.preflight.check_context import CheckContext
    from rig.preflight.verdicts import CheckRow

DESCRIPTION = """\
Check a rig before a run: open every device its config names and move nothing (unless --move).

Sections, in order: ports (present, permitted, the USB adapter's latency timer), servos (each
configured ID found; model, firmware, input voltage, temperature, hardware error, the operating mode
its role needs), loadcell (listened to for --window-s: banner, rate and jitter, noise in counts and
newtons, unique values, saturation, gaps, clock skew, the stale timeout), line (slack now: the cell
within limits.zero_tolerance_n of its zero), limits (protocol ceilings, rig ceiling, winch stall
tension, load-cell capacity), move (only with --move: a small supervised jog of the winch that
checks the reel direction and measures the line stiffness; the winch ends where it started, torque
off).

Without --rig the built-in simulated rig is checked.
"""

WINDOW_DEFAULT_S = 5.0
WINDOW_RANGE_S = (1.0, 600.0)

EPILOG = """\
examples:
  rig check --rig my-lab.yaml
  rig check --rig my-lab.yaml --only ports servos
  rig check --rig my-lab.yaml --only loadcell --window-s 60   # the cell alone, a minute
  rig check --rig my-lab.yaml --move            # jog, then offer to write the findings
  rig check --rig my-lab.yaml --move --write    # and write them without asking
  rig check --rig my-lab.yaml --protocol protocols/joint_estimation.yaml --json

JSON (--json): {"rig", "rig_kind", "rows": [{"section", "check", "verdict", "measured", "fix"}, ...],
"counts": {"pass", "warn", "fail"}, "written": [...]}.
Exit codes: 0 every check passed (warnings allowed); 1 a check failed; 2 invalid input.
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig check`."""
    from rig.preflight.sections import section_names

    parser = subparsers.add_parser(
        "check",
        help=COMMANDS["check"],
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--rig", type=Path, default=None, metavar="CONFIG", help="rig config (default: the simulated rig)"
    )
    parser.add_argument(
        "--only", nargs="+", choices=section_names(), metavar="SECTION", help="run only these sections"
    )
    parser.add_argument(
        "--protocol",
        type=Path,
        action="append",
        default=[],
        metavar="PROTOCOL",
        help="also check this protocol's ceiling and ramp against the rig (repeatable)",
    )
    parser.add_argument(
        "--move", action="store_true", help="jog the winch: reel direction and line stiffness"
    )
    parser.add_argument(
        "--jog-travel-rev",
        type=float,
        default=1.0,
        metavar="REV",
        help="with --move: the most the winch turns each way, 0.01-5 rev (default 1)",
    )
    parser.add_argument(
        "--write",
        action="store_true",
        help="with --move: write the measured reel direction and stiffness into CONFIG without asking",
    )
    parser.add_argument(
        "--sysfs-root",
        type=Path,
        default=DEFAULT_SYSFS_ROOT,
        metavar="DIR",
        help="where USB-serial latency timers are read (default /sys; `rig sim servos --sysfs-root`)",
    )
    parser.add_argument(
        "--window-s",
        type=float,
        default=WINDOW_DEFAULT_S,
        metavar="S",
        help=f"how long the load cell is listened to after its first sample, {WINDOW_RANGE_S[0]:g}-"
        f"{WINDOW_RANGE_S[1]:g} s (default {WINDOW_DEFAULT_S:g}; longer measures the clock skew better)",
    )
    parser.add_argument("--seed", type=int, default=0, help="simulated rig: its seed (default 0)")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Run the sections, print the rows, offer to write the jog's findings; returns the exit code."""
    # Imported here, so that `--help` stays quick; a Ctrl-C meanwhile waits for the imports
    # (one landing in importlib's lock cleanup would be printed and swallowed there).
    with interrupts_deferred():
        from rig.inputs.files import parse_yaml, read_text_file
        from rig.inputs.protocol import load_protocol
        from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, parse_rig_config
        from rig.preflight.check_context import CheckContext, CheckOptions
        from rig.preflight.devices import check_devices
        from rig.preflight.sections import run_sections
        from rig.preflight.verdicts import Verdict, exit_code
        from rig.sim.settings import check_simulation

    if args.write and not args.move:
        raise InputError("--write: only with --move (it writes what the jog measured)")
    if not 0.01 <= args.jog_travel_rev <= 5:  # NaN fails too
        raise InputError(f"--jog-travel-rev {args.jog_travel_rev}: allowed: 0.01 to 5")
    lo, hi = WINDOW_RANGE_S
    if not (math.isfinite(args.window_s) and lo <= args.window_s <= hi):
        raise InputError(f"--window-s {args.window_s}: allowed: {lo:g} to {hi:g}")
    if not 0 <= args.seed < 2**63:
        raise InputError(f"--seed {args.seed}: allowed: 0 to 2^63-1")
    path = args.rig if args.rig is not None else DEFAULT_RIG_CONFIG
    text = read_text_file(path, what="a rig config YAML file")
    # Parsed without the tension-cap refusal of `load_rig_config`: here the cap is a row of its own.
    config = parse_rig_config(parse_yaml(text, str(path)), source=str(path), text=text, base_dir=path.parent)
    check_simulation(config)
    protocols = tuple(
        load_protocol(
            p, seed=args.seed, joint_count=config.article.joint_count, joints_from=config.joints_from
        )
        for p in args.protocol
    )
    ctx = CheckContext(
        config,
        CheckOptions(
            move=args.move,
            sysfs_root=args.sysfs_root,
            protocols=protocols,
            jog_travel_rev=args.jog_travel_rev,
            loadcell_window_s=args.window_s,
        ),
        lambda: check_devices(config, seed=args.seed),
    )
    rows = run_sections(ctx, args.only or ())
    if not args.json:
        print(_text(rows))  # what was measured, before any question about writing it
    written = _offer_to_write(args, ctx, path == DEFAULT_RIG_CONFIG)
    code = exit_code(rows)
    counts = {v.value: sum(r.verdict is v for r in rows) for v in Verdict}
    if args.json:
        emit_json(
            {
                "rig": str(path),
                "rig_kind": config.kind.value,
                "rows": [r.to_json() for r in rows],
                "counts": counts,
                "written": written,
            }
        )
        return code
    for line in written:
        print(f"wrote {line} into {path}")
    summary = ", ".join(f"{n} {name}" for name, n in counts.items())
    verdict = "ready" if code == ExitCode.OK else "NOT ready"
    print(f"\n{config.name} ({config.kind.value}): {summary}: {verdict}")
    if written:
        again = f"rig check --rig {path}" + (" --move" if args.move else "")
        print(
            f"the rows above are of the config before the write; run `{again}` again to check it as written"
        )
    return code


def _text(rows: list[CheckRow]) -> str:
    """The rows grouped by section, one line each, the fix indented under a warn or fail."""
    lines: list[str] = []
    section = None
    for row in rows:
        if row.section != section:
            section = row.section
            lines.append(f"{'' if not lines else chr(10)}[{section}]")
        lines.append(f"  {row.verdict.value.upper():4}  {row.check}: {row.measured}")
        if row.fix:
            lines.append(f"        fix: {row.fix}")
    return "\n".join(lines)


def _offer_to_write(args: argparse.Namespace, ctx: CheckContext, built_in: bool) -> list[str]:
    """Write the jog's findings into the config: with --write, or after a yes at a terminal."""
    from rig.preflight.config_update import pending_changes, write_changes

    findings = ctx.jog_findings
    if findings is None:
        return []
    changes = pending_changes(ctx.config, findings.reel_direction, findings.stiffness_n_per_m)
    if not changes:
        return []
    wanted = ", ".join(f"{key}: {value}" for key, value in changes.items())
    if built_in:
        print(f"rig check: not written ({wanted}): the built-in rig config is not edited", file=sys.stderr)
        return []
    if not args.write:
        if args.json or not sys.stdin.isatty():
            print(
                f"rig check: not written ({wanted}): no terminal to ask; --write writes it", file=sys.stderr
            )
            return []
        answer = input(f"Write what the jog measured ({wanted}) into {ctx.config.source}? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            return []
    return write_changes(ctx.config, changes)
