"""`rig run PROTOCOL`: run automated slip trials, log them to MCAP, refit the model after every trial."""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig.cli.commands import COMMANDS
from rig.cli.live_options import add_live_address
from rig.cli.output import emit_json, format_table
from rig.cli.run_options import add_protocol_and_rig
from rig.errors import InputError
from rig.hw.usb_latency import DEFAULT_SYSFS_ROOT
from rig.safety.interrupts import interrupts_deferred, interrupts_held
from rig.sim.kinds import DeviceLevel
from rig.vocabulary import ConfigurationSourceKind, RigKind, StepKind

if TYPE_CHECKING:
    from model.fit import FitSummary
    from model.fit_keys import EstimateSummary
    from model.payload_errors import PayloadErrorStats
    from rig.inputs.protocol import Protocol
    from rig.inputs.rig_config import RigConfig
    from rig.log.live.publisher import LivePublisher
    from rig.runner.execute import PreparedRun, RunReport, RunRequest
    from rig.sim.truth import RunTruth

DESCRIPTION = """\
Run a protocol of automated slip trials. The winch (a Dynamixel servo in current-based position
mode) reels the line until a joint slips; the slip detector finds the peak tension; after every
trial the model is refitted (joint estimation: k, mu_s*delta0 and the capacity with 99 % bounds;
link validation: prediction before the trial, error after it, per-joint capacities).

Without --rig the built-in simulated rig is used: the real drivers talk byte for byte to
emulated servos and an emulated load cell, in virtual time (as fast as the CPU allows).

Everything is logged to OUT/RUN_ID.mcap; OUT/RUN_ID.journal.json lets `--resume RUN_ID` finish
an interrupted run without repeating or losing a trial. One process at a time works on a run
(OUT/RUN_ID.lock); a crashed run can always be resumed. Every way out of a run releases the line
tension and then turns torque off.

exit codes: 0 done; 1 stopped by a fault or an interlock (the summary and --json say whether the
safe state was verified); 2 invalid input (nothing started); 130 interrupted.
"""

EXAMPLES = """\
examples:
  rig run protocols/joint_estimation.yaml                 # simulated rig, virtual time
  rig run protocols/link_validation.yaml --seed 3 --json
  rig run protocols/smoke.yaml --dry-run                  # plan, limit checks, duration
  rig run protocols/joint_estimation.yaml --rig protocols/rigs/my-lab.yaml
  rig run --resume 20261121T101500-joint_estimation    # its protocol and rig, from the journal
"""


DEFAULT_OUT_DIR = Path("logs")


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig run`."""
    p = subparsers.add_parser(
        "run",
        help=COMMANDS["run"],
        description=DESCRIPTION,
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_protocol_and_rig(p, resumable=True)
    p.add_argument(
        "--out", type=Path, default=DEFAULT_OUT_DIR, metavar="DIR", help="where logs go (default: logs/)"
    )
    p.add_argument(
        "--seed", type=int, default=0, metavar="N", help="seed for shuffling and the simulator (default 0)"
    )
    p.add_argument(
        "--devices",
        choices=tuple(DeviceLevel),
        default=DeviceLevel.BYTE,
        help="simulated devices: byte (default: the real drivers on emulators) or object (same world, "
        "no bytes; faster, for studies)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="simulation in real time instead of virtual time (e.g. to watch it)",
    )
    p.add_argument(
        "--run-id",
        default=None,
        metavar="ID",
        help="name of the run: 1-100 letters, digits, '.', '_', '-' (default: UTC time + protocol name)",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="print the plan, limit checks and duration; move nothing"
    )
    p.add_argument(
        "--resume",
        default=None,
        metavar="ID",
        help="continue run ID (in the same --out) where it stopped, with the protocol and rig config it "
        "started with (given, they must have the same content)",
    )
    p.add_argument(
        "--sysfs-root",
        type=Path,
        default=DEFAULT_SYSFS_ROOT,
        metavar="DIR",
        help="where a hardware rig's USB-serial latency timers are read at connect (default /sys; "
        "`rig sim servos --sysfs-root`)",
    )
    p.add_argument(
        "--live",
        action="store_true",
        help="serve the run live over the Foxglove WebSocket protocol (open ws://HOST:PORT in Foxglove)",
    )
    add_live_address(p, "--live")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout and nothing else")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Handle `rig run`."""
    # Imported here, so that `--help` stays quick; a Ctrl-C meanwhile waits for the imports
    # (one landing in importlib's lock cleanup would be printed and swallowed there).
    with interrupts_deferred():
        from rig.rigs import check_session_inputs, open_rig
        from rig.runner.execute import claim_run, execute_run, validate_run
        from rig.runner.journal import MAX_SEED
        from rig.runner.progress import make_progress
        from rig.runner.sinks import LiveSink, RunSink
        from rig.sim.settings import check_simulation

    if not 0 <= args.seed <= MAX_SEED:
        raise InputError(f"--seed {args.seed}: allowed: an integer from 0 to {MAX_SEED}")
    if args.resume is not None and args.run_id is not None:
        raise InputError("--resume and --run-id: give one of them (a resumed run keeps its id)")
    if args.protocol is None and args.resume is None:
        raise InputError("PROTOCOL: required to start a run (`rig run --resume RUN_ID` continues one)")
    # Everything is validated before anything is written (the --out directory, the lock, the journal),
    # with the files the session will read; then the run is claimed.
    prepared = validate_run(_request(args))
    if args.dry_run:
        return _dry_run(args, prepared)
    check_simulation(prepared.config)  # the simulator's section, which the runner keeps as written
    check_session_inputs(prepared.config)
    _require_a_terminal_for_prompts(prepared.protocol, prepared.config)
    live = _start_live(args)  # a port in use is an InputError before anything is written or moves
    try:
        claim_run(prepared)  # makes --out, locks the run; InputError -> exit 2
        try:
            rig = open_rig(prepared, devices=DeviceLevel(args.devices))
            sinks: list[RunSink] = [make_progress(args.json)]
            if live is not None:
                sinks.append(LiveSink(live))
            report = execute_run(prepared, rig, *sinks)
        finally:
            prepared.release()
    finally:
        if live is not None:
            live.close()
    with interrupts_held():  # the run has ended: its report is printed whole
        if args.json:
            emit_json(report.as_json())
        else:
            print(_summary(report, args.out), file=sys.stderr if report.exit_code else sys.stdout)
    return report.exit_code


def _start_live(args: argparse.Namespace) -> LivePublisher | None:
    """The live view's server if `--live` (its address on stderr unless `--json`)."""
    if not args.live:
        return None
    if not 0 <= args.live_port <= 65535:
        raise InputError(f"--live-port {args.live_port}: allowed: 0 to 65535")
    from rig.log.live.publisher import LivePublisher

    live = LivePublisher(host=args.live_host, port=args.live_port)
    if not args.json:
        print(f"live view: {live.url} (Foxglove: Open connection, Foxglove WebSocket)", file=sys.stderr)
    return live


def _dry_run(args: argparse.Namespace, prepared: PreparedRun) -> int:
    """Validate what a real run validates, then print the plan; no device is opened, nothing written.

    `prepared` is validated as a real run's is (and not claimed); the files the session would read
    are checked too.
    """
    from rig.rigs import check_session_inputs
    from rig.runner.limits import plan_summary
    from rig.sim.settings import check_simulation

    check_simulation(prepared.config)
    notes = _calibration_not_made_yet(prepared.config)
    if not notes:
        check_session_inputs(prepared.config)
    plan = plan_summary(prepared.protocol, prepared.config)
    if args.json:
        emit_json({**plan.as_json(), "notes": notes} if notes else plan.as_json())
        return 0
    rows = []
    for t in plan.trials:
        where = f"{t.distance_m:.3f} m" if t.distance_m is not None else f"config {t.configuration_index}"
        rows.append([t.trial_id, t.kind, where, t.repeat, " ".join(t.steps)])
    count = f"{len(rows)} trials" if not plan.adaptive else f"{len(rows)} trials planned ahead"
    print(f"protocol {plan.protocol} on rig {plan.rig} ({plan.rig_kind}): {count}\n")
    print(format_table(["trial", "kind", "distance / config", "repeat", "steps"], rows))
    for block in plan.adaptive:
        startup = ", ".join(str(block.first_trial_id + i) for i in range(block.startup_trials))
        print(
            f"\nblock {block.block} (adaptive, joint {block.joint}): trials {startup} are its start-up "
            f"(a distance whose predicted slip force is too high is replaced by the shortest safe one); "
            f"{block.text}"
        )
    print("\nlimit checks:")
    print(
        format_table(
            ["check", "value", "limit", "ok"],
            [[c.name, c.value, c.limit, "yes" if c.ok else "NO"] for c in plan.limit_checks],
        )
    )
    minutes = plan.estimated_duration_s / 60
    print(f"\nestimated duration: {minutes:.1f} min of rig time ({plan.duration_assumption})")
    resolution_n = plan.slip_load_resolution_n
    print(
        f"slip-load resolution: one winch count is {resolution_n * 1000:.1f} mN of tension, 0.5 % of a "
        f"{resolution_n / 0.005:.1f} N slip; a softer line reads smaller slips finer (docs/hardware.md, "
        '"Line compliance and the slip load\'s resolution")'
    )
    for note in notes:
        print(f"note: {note}")
    for warning in plan.warnings:
        print(f"warning: {warning}")
    print("dry run: nothing was moved")
    return 0


# Steps that wait for a person on a hardware rig (bending and resetting by hand where it has no
# forks; with `configuration.source: operator` also the measurement, and the question after a slip).
_OPERATOR_STEPS = frozenset({StepKind.PROMPT, StepKind.BEND, StepKind.RESET})


def _require_a_terminal_for_prompts(protocol: Protocol, config: RigConfig) -> None:
    """Refuse, before anything moves, a hardware run whose operator steps could never be confirmed.

    Over `ssh HOST rig run ...` (no -t), from cron or with stdin from /dev/null there is no terminal
    to press Enter in; the first prompt would stop the run half way.
    """
    if config.kind != RigKind.HARDWARE or sys.stdin is None or sys.stdin.isatty():
        return
    templates = [t.steps for t in protocol.trials] + [b.steps for b in protocol.adaptive]
    # Forks bend and straighten the link themselves: only a rig without them needs hands for those.
    forks = any(s.component is not None for s in config.servos.benders)
    by_person = _OPERATOR_STEPS - {StepKind.BEND, StepKind.RESET} if forks else _OPERATOR_STEPS
    if config.configuration.source == ConfigurationSourceKind.OPERATOR:
        by_person = by_person | {StepKind.MEASURE, StepKind.RAMP_UNTIL_SLIP}  # angles; which joint moved
    waits = sorted({s.kind.value for steps in templates for s in steps if s.kind in by_person})
    if waits:
        raise InputError(
            f"{protocol.source}: its {', '.join(waits)} steps wait for the operator to press Enter, and "
            "stdin is not a terminal; run it from one: `ssh -t HOST rig run ...`, best inside tmux or "
            "screen so that a dropped connection does not stop the run"
        )


def _calibration_not_made_yet(config: RigConfig) -> list[str]:
    """A hardware rig's calibration file that does not exist yet: a note for a dry run, not a refusal.

    The bring-up order is plan first, then calibrate (docs/hardware.md); a real run still refuses.
    """
    path = config.loadcell.calibration_path
    if config.kind != RigKind.HARDWARE or path is None or path.exists():
        return []
    return [
        f"{config.source}: loadcell.calibration {path} does not exist yet; make it with "
        f"`rig calibrate --rig {config.source} --reference-kg M` before a run"
    ]


def _request(args: argparse.Namespace) -> RunRequest:
    from rig.runner.execute import RunRequest

    return RunRequest(
        protocol_path=args.protocol,
        rig_path=args.rig,
        out_dir=args.out,
        seed=args.seed,
        realtime=args.realtime,
        run_id=args.run_id,
        resume=args.resume,
        sysfs_root=args.sysfs_root,
    )


def resume_command(run_id: str, out_dir: Path) -> str:
    """The command that continues a run, as it can be typed (`--out` when not the default)."""
    command = f"rig run --resume {shlex.quote(run_id)}"
    if out_dir != DEFAULT_OUT_DIR:
        command += f" --out {shlex.quote(str(out_dir))}"
    return command


def _summary(report: RunReport, out_dir: Path) -> str:
    from model.fit import nonnegative_bounds

    outcomes: dict[str, int] = {}
    for trial in report.trials:
        outcomes[trial.outcome.value] = outcomes.get(trial.outcome.value, 0) + 1
    counts = f" ({', '.join(f'{n} {name}' for name, n in outcomes.items())})" if outcomes else ""
    lines = [
        f"run {report.run_id}: {report.completed}/{report.planned} trials done{counts}; log {report.log}"
    ]
    lines += [summary.text for summary in report.design]  # adaptive blocks: where they stopped, and why
    if report.aborted:
        if report.safe_state_verified and not report.resumable:  # every trial done, nothing measured
            lines.append(f"FAILED: {report.reason} (hardware left safe)")
        elif report.safe_state_verified:
            lines.append(
                f"STOPPED: {report.reason} (hardware left safe; `{resume_command(report.run_id, out_dir)}` "
                "continues)"
            )
        else:
            lines.append(f"STOPPED, SAFE STATE NOT VERIFIED: {report.reason}")
    est = report.estimate
    if est is not None:
        # k, the capacity and mu_s·delta0 cannot be negative: bounds shown cut at 0 (model.fit)
        lo, hi = nonnegative_bounds(est.k_ci)
        clo, chi = nonnegative_bounds(est.capacity_ci_nm)
        mlo, mhi = nonnegative_bounds(est.mu_delta0_ci_pa)
        lines.append(
            format_table(
                ["quantity", "estimate", f"{est.level * 100:g} % bounds", "unit"],
                [
                    ["k", est.k, f"[{lo:.5g}, {hi:.5g}]", "kg·m"],
                    ["capacity N_max", est.capacity_nm, f"[{clo:.5g}, {chi:.5g}]", "N·m"],
                    [f"mu_s·delta0 (c={est.constant})", est.mu_delta0_pa, f"[{mlo:.5g}, {mhi:.5g}]", "Pa"],
                    ["RMSE", est.rmse, "", "kg"],
                    ["R²", est.r2, "", ""],
                    ["n", est.n, "", "trials"],
                    *_paper_rows(report),
                ],
            )
        )
        detail = report.estimate_detail
        if detail is not None:
            lines.append(_estimator_text(detail))
    if report.joints:
        lines.append(
            format_table(
                ["joint", "capacity N·m", "lower", "upper"],
                [[j.joint, j.capacity_nm, j.ci_lo_nm, j.ci_hi_nm] for j in report.joints],
            )
        )
    pe = report.percentage_errors
    if pe is not None:
        lines.append(_percentage_text(pe))
    if report.truth is not None:
        from rig.sim.truth import RunTruth

        assert isinstance(report.truth, RunTruth)  # the only truth a rig reports is the simulator's
        lines.append(_truth_text(report.truth, est))
    return "\n\n".join(lines)


def _paper_rows(report: RunReport) -> list[list[Any]]:
    """The paper's k and capacity as extra rows when the run's estimator is another one."""
    from model.fit import nonnegative_bounds

    detail = report.estimate_detail
    if detail is None or detail.estimate.estimator == "paper" or detail.paper is None:
        return []
    paper = detail.paper
    (lo, hi), (clo, chi) = nonnegative_bounds(paper.k_ci), nonnegative_bounds(paper.capacity_ci_nm)
    return [
        ["k (paper's fit)", paper.k, f"[{lo:.5g}, {hi:.5g}]", "kg·m"],
        ["capacity (paper's fit)", paper.capacity_nm, f"[{clo:.5g}, {chi:.5g}]", "N·m"],
    ]


def _estimator_text(detail: EstimateSummary) -> str:
    """Which estimator made the estimate, and what it found of the scatter."""
    est = detail.estimate
    text = f"estimator {est.estimator}"
    if est.estimator != "paper":
        text += (
            f": scatter sd(m)² = a² + (b·m)² with a = {est.scatter_a_kg:.3g} kg, b = {est.scatter_b:.3g}; "
            f"{est.scatter_model}"
        )
    if est.diagnostic is not None:
        d = est.diagnostic
        text += (
            f" (likelihood ratio: additive p = {d.p_additive:.3g}, "
            f"multiplicative p = {d.p_multiplicative:.3g}"
            f"{'' if d.decided else '; the data cannot tell'})"
        )
    if est.n_censored:
        text += f"; {est.n_censored} no-slip trial(s) as lower bounds"
    if est.note:
        text += f"; {est.note}"
    return text


def _percentage_text(pe: PayloadErrorStats) -> str:
    parts = [f"link validation: {len(pe.percentage_errors)} predictions"]
    parts.append(f"percentage error mean {pe.mean_pct:.2f} % ± {pe.std_pct:.2f} %")
    for threshold, share in pe.share_below_pct:
        parts.append(f"{share * 100:.1f} % of errors below {threshold:g} %")
    return "; ".join(parts)


def _truth_text(truth: RunTruth, est: FitSummary | None) -> str:
    k = truth.k_kg_m
    text = f"simulator truth: k = {k:.5g} kg·m"
    if est is not None:
        lo, hi = est.k_ci
        off = f"estimate off by {(est.k - k) / k * 100:+.2f} %"
        if math.isfinite(lo) and math.isfinite(hi):  # an estimates file may give no bounds on k
            off = f"{'inside' if lo <= k <= hi else 'OUTSIDE'} the bounds; {off}"
        text += f" ({off})"
    return text + f", capacity {truth.capacity_nm:.4f} N·m"
