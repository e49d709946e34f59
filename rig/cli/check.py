"""`rig check --only loadcell`: the load-cell diagnostic of a rig config, one row per finding.

A thin command (the full pre-flight `rig check`, with ports, servos, limits and the line, is being
written beside it and takes this section over): parse, open the cell the config names, listen
(`rig.preflight.loadcell.listen`), print the rows (`diagnose`) or JSON, exit 0 (warnings allowed)
or 1 (a check failed).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from rig.cli.output import emit_json, format_table
from rig.errors import InputError

SECTIONS = ("loadcell",)
WINDOW_RANGE_S = (1.0, 600.0)


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig check`."""
    parser = subparsers.add_parser(
        "check",
        help="pre-flight check of a rig (here: --only loadcell, the load-cell diagnostic)",
        description=(
            "Listen to the load cell the rig config names, through the real driver, and report its "
            "banner, measured rate and jitter, noise in counts and newtons (keep the line slack), "
            "unique values, saturation, gaps and damaged lines and its clock skew in ppm, each with "
            "a verdict and what to do. Exit 0 when nothing failed (warnings allowed), 1 when a check "
            "failed, 2 on invalid input. Without --rig the built-in simulated rig is checked."
        ),
    )
    parser.add_argument("--rig", type=Path, default=None, metavar="CONFIG", help="rig config")
    parser.add_argument(
        "--only", nargs="+", choices=SECTIONS, default=list(SECTIONS), metavar="SECTION", help="loadcell"
    )
    parser.add_argument(
        "--window-s",
        type=float,
        default=10.0,
        help=f"how long to listen after the first sample, {WINDOW_RANGE_S[0]:g}-{WINDOW_RANGE_S[1]:g} s "
        "(default 10)",
    )
    parser.add_argument("--seed", type=int, default=0, help="simulated rig: random seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print the rows as one JSON object")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Run the diagnostic; the exit code from the rows."""
    from rig.preflight.loadcell import config_load_cell, diagnose, listen
    from rig.preflight.verdicts import Verdict, exit_code
    from rig.rig_config import load_rig_config

    lo, hi = WINDOW_RANGE_S
    if not (math.isfinite(args.window_s) and lo <= args.window_s <= hi):
        raise InputError(f"--window-s {args.window_s}; allowed: {lo:g}-{hi:g}")
    config = load_rig_config(args.rig)
    load_cell, clock = config_load_cell(config, seed=args.seed)
    rows = diagnose(listen(load_cell, clock, args.window_s, config.loadcell.rate_hz))
    if args.json:
        emit_json(
            {
                "rig": str(config.source),
                "rig_kind": config.kind.value,
                "rows": [row.to_json() for row in rows],
                "counts": {v.value: sum(1 for r in rows if r.verdict is v) for v in Verdict},
            }
        )
    else:
        table = [(r.section, r.check, r.verdict.value, r.measured, r.fix) for r in rows]
        print(format_table(["section", "check", "verdict", "measured", "fix"], table))
    return int(exit_code(rows))
