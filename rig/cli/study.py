"""`rig study PROTOCOL --seeds 0-199`: a protocol over many seeds on the simulated rig, estimators scored."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING

from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.cli.run_options import add_protocol_and_rig
from rig.errors import ExitCode, InputError
from rig.inputs.files import check_out_dir
from rig.safety.interrupts import interrupts_deferred
from rig.sim.kinds import DeviceLevel
from rig.vocabulary import RigKind, TrialKind

if TYPE_CHECKING:
    from rig.inputs.protocol import Protocol
    from rig.study.statistics import StudySummary
    from rig.study.worker import RunRecord, StudySpec

DESCRIPTION = """\
Plan an experiment before running it: run PROTOCOL on the simulated rig once per seed (each seed
draws its own world: joint capacities, trial-to-trial scatter, sensor noise), estimate k from each
run's trials with every estimator, and compare with the world's true k.

Per estimator it reports:
  coverage        how often the 99 % bounds contain the true k (should be about 0.99), with the
                  95 % Clopper-Pearson interval of that proportion
  bias_rel        mean relative error of k
  rmse_rel        root mean square relative error of k
  mse_over_crlb   mean squared error over the Cramér-Rao bound for the run's own distances and
                  the true scatter (1.0 is the best any unbiased estimator can do)
  trials          trials a run used: mean, median and 90th percentile (an adaptive design
                  stops when its bound is narrow enough, so this is its cost)
  coverage at the stop (adaptive blocks): the coverage split by how each series stopped,
                  target reached or budget used up (or no safe distance), with 95 % intervals
and how many runs were aborted (with their reasons). Slips enter the fit as measured slip loads,
no-slip trials (nothing slipped up to the force limit) as lower bounds.

Change the protocol (distances, repeats) or the rig config (the simulation: section) and compare:
that is how to choose the number of trials, the distances and the estimator.

Protocols: the joint_estimation blocks are scored, fixed (`distances_m` x `repeats`) and adaptive
(`design: adaptive`, whose planner chooses the distances and when to stop) alike, alone or mixed.
A case is one run's fixed trials on one joint, or one adaptive block's own trials (the data its
stopping rule saw). A protocol without a joint_estimation block is not supported (exit 2, naming
the blocks found): a link_validation block's capacities come from a prior estimate, not from its
own trials.

The runs use object-level simulated devices by default: the same world, motion model and load-cell
signal model as the byte-level rig, without the packets and lines (a test holds a seed at both
levels to the same trials and outcomes, slip loads apart by load-cell noise only); --devices byte
runs the real drivers on the emulators, as `rig run` does. No MCAP is written (reproduce any seed
with its log: `rig run PROTOCOL --seed N`). With --out DIR the table of every run x joint x
estimator goes to DIR/study.parquet, written whole or not at all.

exit codes: 0 done (aborted runs are counted, not failures); 2 invalid input (nothing started);
130 interrupted (workers stopped, nothing written).
"""

EXAMPLES = """\
examples:
  rig study protocols/joint_estimation.yaml --seeds 0-199 --jobs 2
  rig study protocols/joint_estimation.yaml --seeds 0-49 --json
  rig study protocols/joint_estimation_adaptive.yaml --seeds 0-199 --jobs 2
  rig study my_design.yaml --rig protocols/rigs/my-sim.yaml --seeds 0,3,7,100-119 --out studies/out
  rig study protocols/joint_estimation.yaml --seeds 0-999 --scheduler tcp://10.0.0.5:8786
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig study`."""
    p = subparsers.add_parser(
        "study",
        help=COMMANDS["study"],
        description=DESCRIPTION,
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_protocol_and_rig(p, simulated_only=True)
    p.add_argument(
        "--seeds",
        required=True,
        metavar="SEEDS",
        help="seeds to run: ranges and lists, e.g. 0-199, 0,3,7 or 0-9,20,30-39",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="worker processes (default: the number of CPUs; 1 runs in this process)",
    )
    p.add_argument(
        "--devices",
        choices=(DeviceLevel.OBJECT, DeviceLevel.BYTE),
        default=DeviceLevel.OBJECT,
        help="simulated devices: object (default, fast) or byte (the real drivers on emulators)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="write DIR/study.parquet (every run x estimator)",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on a Dask cluster, e.g. tcp://host:8786 (needs the `study` extra: dask[distributed])",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout and nothing else")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Handle `rig study`."""
    # Imported here, so that `--help` stays quick; a Ctrl-C meanwhile waits for the imports
    # (one landing in importlib's lock cleanup would be printed and swallowed there).
    with interrupts_deferred():
        from model.k_estimators import ESTIMATOR_NAMES
        from rig.study.executor import require_dask, run_dask, run_local
        from rig.study.seeds import parse_seeds
        from rig.study.statistics import summarise
        from rig.study.table import write_table

    seeds = parse_seeds(args.seeds)
    jobs = _jobs(args.jobs)
    if args.out is not None:
        check_out_dir(args.out)
    spec = _checked_spec(args)
    if args.scheduler is not None:
        require_dask()  # a missing extra is an input error before anything runs
    records: list[RunRecord] = []
    with _progress(len(seeds), quiet=args.json) as advance:
        if args.scheduler is not None:
            records = run_dask(spec, seeds, args.scheduler, advance)
        else:
            records = run_local(spec, seeds, jobs, advance)
    summary = summarise(str(args.protocol), seeds, records, ESTIMATOR_NAMES, spec.level)
    table = write_table(args.out, records, ESTIMATOR_NAMES) if args.out is not None else None
    if args.json:
        emit_json(summary.as_json())
    else:
        print(_text(summary, spec, table))
    return ExitCode.OK


def _jobs(jobs: int | None) -> int:
    if jobs is None:
        return max(1, os.cpu_count() or 1)
    if not 1 <= jobs <= 256:
        raise InputError(f"--jobs {jobs}: allowed: 1 to 256")
    return int(jobs)


def _checked_spec(args: argparse.Namespace) -> StudySpec:
    """Everything a run will read, validated once here (exit 2 before any worker starts)."""
    # As in `run`: imported here, a Ctrl-C meanwhile deferred.
    with interrupts_deferred():
        from rig.rigs import check_session_inputs
        from rig.runner.execute import RunRequest, prepare_run
        from rig.sim.settings import check_simulation, require_simulated
        from rig.study.worker import StudySpec

    request = RunRequest(protocol_path=args.protocol, rig_path=args.rig, out_dir=Path("."), seed=0)
    prepared = prepare_run(request, dry_run=True)
    config = prepared.config
    check_simulation(config)
    if config.kind != RigKind.SIMULATED:
        raise InputError(
            f"--rig {config.source}: kind {config.kind}; allowed: a simulated rig (a study needs the truth)"
        )
    check_session_inputs(config)
    if args.devices == DeviceLevel.OBJECT and require_simulated(config).faults:
        raise InputError(
            f"{config.source}: simulation/faults: timed faults act on the emulators' bytes; "
            "allowed: --devices byte for a config with faults"
        )
    if TrialKind.JOINT_ESTIMATION not in prepared.protocol.kinds:
        raise InputError(
            f"{args.protocol}: blocks: {_block_kinds(prepared.protocol)}; not supported by rig study, which "
            "scores joint_estimation blocks, fixed or adaptive (a link_validation block's capacities come "
            "from a prior estimate, not its own trials); allowed: a protocol with a joint_estimation block"
        )
    return StudySpec(
        protocol_path=str(args.protocol),
        rig_path=None if args.rig is None else str(args.rig),
        devices=DeviceLevel(args.devices),
    )


def _block_kinds(protocol: Protocol) -> str:
    """The kinds of the protocol's blocks with how many of each, e.g. `link_validation x 2`."""
    blocks: dict[int, str] = {t.block: t.kind.value for t in protocol.trials}
    blocks.update({b.block: f"{b.kind.value} (adaptive)" for b in protocol.adaptive})
    counts: dict[str, int] = {}
    for kind in blocks.values():
        counts[kind] = counts.get(kind, 0) + 1
    return ", ".join(f"{kind} x {n}" for kind, n in sorted(counts.items()))


class _progress:
    """A rich progress bar on stderr (none with --json); the context yields the per-record callback."""

    def __init__(self, total: int, *, quiet: bool) -> None:
        self.total = total
        self.quiet = quiet
        self.aborted = 0

    def __enter__(self) -> _Advance:
        if self.quiet:
            return _Advance(None, None)
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.bar = Progress(
            TextColumn("study"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[aborted]} aborted"),
            TimeRemainingColumn(),
            console=Console(stderr=True),
            transient=True,
        )
        self.bar.start()
        task = self.bar.add_task("runs", total=self.total, aborted=0)
        return _Advance(self.bar, task)

    def __exit__(self, *exc: object) -> None:
        if not self.quiet:
            self.bar.stop()


class _Advance:
    """Counts a finished run on the progress bar."""

    def __init__(self, bar: object | None, task: object | None) -> None:
        self.bar = bar
        self.task = task
        self.aborted = 0

    def __call__(self, record: RunRecord) -> None:
        if record.status != "completed":
            self.aborted += 1
        if self.bar is not None:
            self.bar.update(self.task, advance=1, aborted=self.aborted)  # type: ignore[attr-defined]


def _text(summary: StudySummary, spec: StudySpec, table: Path | None) -> str:
    completed = summary.runs - summary.aborted
    lines = [
        f"study of {summary.protocol}: {summary.runs} runs ({len(summary.seeds)} seeds, {spec.devices}-level "
        f"devices), {summary.aborted} aborted; bounds at {summary.level * 100:g} %"
    ]
    rows = []
    for name, e in summary.estimators.items():
        lo, hi = e.coverage_ci
        rows.append(
            [
                name,
                e.cases,
                f"{e.coverage:.3f}",
                f"[{lo:.3f}, {hi:.3f}]",
                f"{e.bias_rel * 100:+.2f} %",
                f"{e.rmse_rel * 100:.2f} %",
                f"{e.mse_over_crlb:.2f}",
                f"{e.mean_trials:.1f} / {e.median_trials:g} / {e.p90_trials:g}",
                e.failures,
            ]
        )
    lines.append(
        format_table(
            [
                "estimator",
                "cases",
                "coverage",
                "95 % CI",
                "bias",
                "RMSE",
                "MSE/CRLB",
                "trials: mean / median / p90",
                "failed",
            ],
            rows,
        )
    )
    stop_rows = [
        [
            name,
            c.stop_reason.value,
            c.cases,
            f"{c.coverage:.3f}",
            f"[{c.coverage_ci[0]:.3f}, {c.coverage_ci[1]:.3f}]",
        ]
        for name, e in summary.estimators.items()
        for c in e.coverage_by_stop
    ]
    if stop_rows:
        lines.append(
            "coverage at the stop of the adaptive blocks, by how they stopped:\n"
            + format_table(["estimator", "stopped", "cases", "coverage", "95 % CI"], stop_rows)
        )
    if completed == 0:
        lines.append("no run completed: nothing to score")
    for seed, reason in summary.aborted_reasons[:10]:
        lines.append(f"aborted: seed {seed}: {reason}")
    if len(summary.aborted_reasons) > 10:
        lines.append(f"... and {len(summary.aborted_reasons) - 10} more aborted runs (see the table)")
    if table is not None:
        lines.append(f"table: {table}")
    return "\n\n".join(lines)
