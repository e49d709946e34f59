"""`rig replay LOG...`: a logged run back into tables, re-detected slips, refits and a report."""

from __future__ import annotations

import argparse
import warnings
from typing import TYPE_CHECKING, Any

from rig.cli.commands import COMMANDS
from rig.cli.live_options import add_live_address
from rig.cli.output import emit_json, format_table

if TYPE_CHECKING:
    from rig.analysis.replay_run import ReplayResult

DESCRIPTION = """\
Replay a run's MCAP log(s): rebuild the trial table from /rig/trial/result, run the slip detector
again over each trial's raw /rig/loadcell samples (with the logged parameters it must reproduce the
logged slip events exactly), refit the joint-estimation data offline and compare with the online
estimate the run logged, and for link-validation runs compute the payload errors (paper Table IV)
and the base moments at slip (Table V).

LOG is an .mcap file or a directory of them; give every part of a resumed run (or their
directory) to combine them. A damaged or unfinished file replays what it can, with a warning.
"""

EPILOG = """\
--detector KEY=VALUE ... re-detects with changed parameters (after the LOG arguments), e.g.
  rig replay logs/run.mcap --detector drop_fraction=0.2 min_drop_n=0.1
Fields: arm_threshold_n, drop_fraction, min_drop_n, slope_n_per_s, slope_window_s,
cusum_threshold_n, cusum_drift_n_per_s, rearm_below_n, ... (docs/model.md §7; 'none' disables an
optional trigger).

--report DIR writes report.md, PNG figures (fit with 99 % bounds, residuals, payload per
configuration, percentage-error histogram, estimate evolution, force traces: force_traces.png,
or one page per 48 trials, force_traces_1.png, ...), replay.json and the trial table as trials.csv
and trials.parquet. DIR must be new or empty; it appears complete or not at all. Replay reads the
load-cell samples one trial at a time: its memory does not grow with the length of the run.

JSON (--json): files, complete, warnings, trials, estimate (offline refit, `rig fit --json` keys),
online_estimate, online_agreement, redetected_estimate, redetection, links (per trial: the servo
bus's and load-cell line's counts); for link-validation runs also
percentage_errors, base_moments and joints; under simulation truth.
Exit codes: 0 done (also for damaged files, with warnings); 2 invalid input (missing or non-MCAP
file, no rig message readable, a log format version this rig does not read, bad --detector value,
unusable --report directory).

The same from Python, with the run's tables as pandas DataFrames: rig.analysis.open_log
(docs/analysis.md).
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig replay`."""
    parser = subparsers.add_parser(
        "replay",
        help=COMMANDS["replay"],
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("logs", nargs="+", metavar="LOG", help="an .mcap file or a directory of them")
    parser.add_argument("--report", metavar="DIR", help="write a report directory (new or empty)")
    parser.add_argument(
        "--detector",
        nargs="+",
        action="extend",
        default=[],
        metavar="KEY=VALUE",
        help="re-detect with these detector parameters instead of the logged ones",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument(
        "--serve",
        action="store_true",
        help="stream the log to Foxglove over its WebSocket protocol instead (waits for a client)",
    )
    parser.add_argument(
        "--speed", type=float, default=1.0, metavar="X", help="--serve at X times real time (default 1)"
    )
    add_live_address(parser, "--serve")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if args.serve:  # no analysis: nothing of pandas and matplotlib to import
        return _serve(args)
    """Handle `rig replay`; returns the exit code."""
    # Imported here, not at the top: pandas and matplotlib cost a second that `rig --help` should not pay.
    from rig.analysis import LogWarning, open_log
    from rig.analysis.redetect import validate_overrides
    from rig.analysis.report import check_report_dir

    validate_overrides(args.detector)
    if args.report is not None:
        check_report_dir(args.report)
    with warnings.catch_warnings():  # the result lists them: printed below, or in the JSON
        warnings.simplefilter("ignore", LogWarning)
        run = open_log(*args.logs, detector=args.detector)
    result = run.replay_result
    written = run.report(args.report) if args.report is not None else []
    if args.json:
        out: dict[str, Any] = run.json()
        if args.report is not None:
            out["report"] = [str(p) for p in written]
        emit_json(out)
    else:
        print(_text(result))
        if written:
            print(f"\nreport: {written[0].parent} ({len(written)} files)")
    return 0


def _serve(args: argparse.Namespace) -> int:
    """`rig replay --serve`: play the files to a Foxglove client, paced by their log times."""
    import math
    import sys
    import time

    from rig.errors import InputError
    from rig.log.format import schemas
    from rig.log.live.publisher import LivePublisher, serve_log
    from rig.log.reading.reader import mcap_files

    if not (args.speed > 0 and math.isfinite(args.speed)):
        raise InputError(f"--speed {args.speed}: allowed: a positive number (1 = real time)")
    if not 0 <= args.live_port <= 65535:
        raise InputError(f"--live-port {args.live_port}: allowed: 0 to 65535")
    files = mcap_files(args.logs)
    with LivePublisher(host=args.live_host, port=args.live_port, playback=True) as live:
        if not live.wait_ready():
            raise InputError(f"--live-port {args.live_port}: {live.failure or 'the server did not start'}")
        print(f"serving {len(files)} file(s) at {live.url}; waiting for a Foxglove client", file=sys.stderr)

        def wait_for_client() -> None:
            while not any(live.wants(topic) for topic in schemas.TOPICS):
                time.sleep(0.05)
            time.sleep(0.2)  # the client's other subscriptions arrive together

        sent, warnings = serve_log(files, live, speed=args.speed, wait_for_client=wait_for_client)
        stats = live.close()
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    summary = {"files": [str(f) for f in files], "sent": sent, "slow_client_events": stats.slow_client_events}
    if args.json:
        emit_json({**summary, "warnings": warnings})
    else:
        print(
            f"served {sent} messages from {len(files)} file(s); {stats.slow_client_events} slow-client "
            "reports (a client lost messages; foxglove-sdk does not say how many)"
        )
    return 0


def _text(result: ReplayResult) -> str:
    from rig.analysis.replay_tables import (
        base_moments_table,
        estimates_table,
        links_table,
        payload_errors_table,
        trials_table,
    )

    s = result.settings
    lines = [
        f"run {s.run_id or '(unknown)'}  protocol {s.protocol_name or '(unknown)'}  "
        f"files {len(result.parts)}  {'complete' if result.complete else 'INCOMPLETE'}",
    ]
    lines += [f"warning: {w}" for w in result.warnings]
    lines += ["", format_table(*trials_table(result)), "", format_table(*estimates_table(result))]
    agreement = result.agreement
    if agreement.compared:
        verdict = "agree" if agreement.agree else "DIFFER in " + ", ".join(agreement.differing)
        lines.append(
            f"offline refit and last online estimate {verdict} "
            f"(max relative difference {agreement.max_relative_difference:.3g})"
        )
    red = result.redetection_summary()
    lines.append(f"re-detection ({red.source}): {red.matches} of {red.trials} trials give the logged event")
    lines += [f"  trial {m.trial_id} {m.status}: {m.detail}" for m in red.mismatches]
    for title, table in (
        ("device links per trial (servo bus exchanges, load-cell lines)", links_table(result)),
        ("payload errors (Table IV)", payload_errors_table(result)),
        ("base moment at slip (Table V)", base_moments_table(result)),
    ):
        if table is not None:
            lines += ["", title, format_table(*table)]
    return "\n".join(lines)
