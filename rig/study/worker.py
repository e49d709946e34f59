"""One seed of a study: the protocol on a fresh simulated rig, k estimated every way, scored with the truth.

`run_seed` is what a worker process (or a Dask worker) executes; it never raises for a failed run:
whatever stops it becomes an aborted `RunRecord` with its reason. The run is `rig run`'s
(`rig.runner.execute.execute_run`), on the devices the study asks for, with its journal kept in memory
(its estimates file in a temporary directory) and no sink: a study's evidence is its Parquet
table, and an MCAP file per seed would cost a writer process and most of the run's time
(`rig run --seed N` reproduces any seed with its full log).
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path

from model.design import StopReason
from model.fit import DEFAULT_LEVEL
from model.k_estimators import ESTIMATOR_NAMES, check_estimator, crlb_k, estimate_k
from rig.errors import ExitCode
from rig.records import TrialKind, TrialOutcome, TrialResult
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.journal import RunJournal
from rig.sim.kinds import DeviceLevel
from rig.sim.truth import WorldTruth
from rig.study.series import score_series

# Outcomes whose slip mass is a measured slip load, and those whose mass is only a lower bound.


@dataclass(frozen=True, slots=True)
class StudySpec:
    """What every run of a study shares (picklable: it goes to the worker processes)."""

    protocol_path: str
    rig_path: str | None
    devices: DeviceLevel
    level: float = DEFAULT_LEVEL


@dataclass(frozen=True, slots=True)
class EstimatorResult:
    """One estimator's k on one joint of one run (NaNs and `error` when it could not estimate)."""

    estimator: str
    k: float
    k_low: float
    k_high: float
    se: float
    n: int
    n_censored: int
    scatter_model: str
    scatter_a_kg: float
    scatter_b: float
    error: str | None = None


@dataclass(frozen=True, slots=True)
class JointResult:
    """A run's joint-estimation trials on one joint, the truth, and every estimator's k."""

    joint: int
    k_true_kg_m: float
    true_scatter_a_kg: float
    true_scatter_b: float
    distances_m: tuple[float, ...]  # every trial with a mass (slips and censored), in run order
    masses_kg: tuple[float, ...]  # their slip masses (for a censored trial, the mass it held)
    censored: tuple[bool, ...]  # True where the trial reached its force limit without a slip
    n_slips: int
    n_censored: int
    n_excluded: int  # trials without a usable mass (aborted or faulted trials)
    crlb_var: float  # Cramér-Rao bound on var(k_hat) for this design and the true scatter
    estimates: tuple[EstimatorResult, ...]
    block: int | None = None  # the adaptive block these trials are (None: the joint's fixed trials)
    stop_reason: StopReason | None = None  # why that block stopped (None for fixed trials)


@dataclass(frozen=True, slots=True)
class RunRecord:
    """One seed's run: how it ended, what it cost, and the per-joint results."""

    seed: int
    status: str  # "completed" or "aborted"
    reason: str | None
    trials_planned: int
    trials_completed: int
    wall_s: float
    joints: tuple[JointResult, ...]


class _UnsavedJournal(RunJournal):
    """A study run's journal, kept in memory: nothing resumes it, so no file is rewritten per trial.

    `rig run` persists its journal after every trial (write, fsync, rename) so that `--resume` can
    continue; in a study that cost an fsync per trial and bought nothing.
    """

    def save(self) -> None:
        return None


def run_seed(spec: StudySpec, seed: int) -> RunRecord:
    """Run the protocol with `seed` and score every estimator; a failure is an aborted record."""
    start = time.perf_counter()
    planned = 0
    try:
        with tempfile.TemporaryDirectory(prefix="rig-study-") as tmp:
            request = RunRequest(
                protocol_path=Path(spec.protocol_path),
                rig_path=None if spec.rig_path is None else Path(spec.rig_path),
                out_dir=Path(tmp),
                seed=seed,
                run_id=f"study-{seed}",
            )
            prepared = prepare_run(request)
            journal = prepared.journal
            prepared.journal = _UnsavedJournal(**{f.name: getattr(journal, f.name) for f in fields(journal)})
            planned = len(prepared.protocol.planned_trial_ids)
            try:
                rig = open_simulated_rig(prepared, devices=spec.devices)
            except BaseException:
                prepared.release()
                raise
            # No sink: the study keeps the report, no log, and the per-tick rows are not built.
            report = execute_run(prepared, rig, log_file=False)
            world = rig.truth.snapshot().world
    except Exception as exc:  # a broken run is counted, never the end of the study
        return RunRecord(seed, "aborted", f"{type(exc).__name__}: {exc}", planned, 0, _since(start), ())
    if report.exit_code == ExitCode.INTERRUPTED:
        raise KeyboardInterrupt  # Ctrl-C in this process (--jobs 1) stops the study, not just this run
    results = report.trials  # a fresh run's journal: this invocation's trials, in run order
    aborted = report.exit_code != ExitCode.OK
    stops = {summary.block: summary.step.stop for summary in report.design}
    joints = score_series(
        results, prepared.protocol.adaptive, stops, lambda trials: score_joints(trials, world, spec.level)
    )
    return RunRecord(
        seed=seed,
        status="aborted" if aborted else "completed",
        reason=report.reason if aborted else None,
        trials_planned=planned,
        trials_completed=len(results),
        wall_s=_since(start),
        joints=joints,
    )


def _since(start: float) -> float:
    return time.perf_counter() - start


def score_joints(results: Sequence[TrialResult], world: WorldTruth, level: float) -> tuple[JointResult, ...]:
    """Every estimator's k per joint from the joint-estimation trials of `results`, with the truth."""
    a_kg, b = float(world.scatter.a_kg), float(world.scatter.b)  # sd(m)² = a² + (b·m)² of one slip mass
    by_joint: dict[int, list[TrialResult]] = {}
    for r in results:
        if r.kind == TrialKind.JOINT_ESTIMATION:
            by_joint.setdefault(r.joint or 1, []).append(r)
    out = []
    for joint, trials in sorted(by_joint.items()):
        usable = [
            r
            for r in trials
            if r.distance_m is not None
            and r.slip_mass_kg is not None
            and math.isfinite(r.slip_mass_kg)
            and r.slip_mass_kg > 0
            and (r.slipped or r.outcome == TrialOutcome.NO_SLIP)
        ]
        distances = [float(r.distance_m) for r in usable if r.distance_m is not None]
        masses = [float(r.slip_mass_kg) for r in usable if r.slip_mass_kg is not None]
        censored = [not r.slipped for r in usable]  # no slip before the force limit: a lower bound
        joint_result = score_joint(
            joint,
            world.joints[joint - 1].k_kg_m,
            (a_kg, b),
            distances,
            masses,
            censored,
            level,
        )
        out.append(replace(joint_result, n_excluded=len(trials) - len(usable)))
    return tuple(out)


def score_joint(
    joint: int,
    k_true_kg_m: float,
    true_scatter: tuple[float, float],
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool],
    level: float,
) -> JointResult:
    """Every estimator's k from one joint's (distance, mass, censored) trials, scored with the truth.

    `true_scatter` is (a [kg], b) of the world's scatter. A run scores its trials with it, and a study's
    table can be refitted with it later (its rows keep the data); trials left out are not counted.
    """
    distances, masses, flags = (
        list(map(float, distances_m)),
        list(map(float, masses_kg)),
        list(map(bool, censored)),
    )
    a_kg, b = true_scatter
    return JointResult(
        joint=joint,
        k_true_kg_m=k_true_kg_m,
        true_scatter_a_kg=a_kg,
        true_scatter_b=b,
        distances_m=tuple(distances),
        masses_kg=tuple(masses),
        censored=tuple(flags),
        n_slips=len(flags) - sum(flags),
        n_censored=sum(flags),
        n_excluded=0,
        crlb_var=crlb_k(distances, k_true_kg_m, a_kg, b),
        estimates=tuple(_estimate(name, distances, masses, flags, level) for name in ESTIMATOR_NAMES),
    )


def _estimate(
    name: str, distances: list[float], masses: list[float], censored: list[bool], level: float
) -> EstimatorResult:
    nan = math.nan
    try:
        e = estimate_k(check_estimator(name), distances, masses, censored, level)
    except (ValueError, ArithmeticError) as exc:  # numpy's LinAlgError is a ValueError
        return EstimatorResult(name, nan, nan, nan, nan, 0, 0, "", nan, nan, f"{type(exc).__name__}: {exc}")
    return EstimatorResult(
        name, e.k, e.k_ci[0], e.k_ci[1], e.se, e.n, e.n_censored, e.scatter_model, e.scatter_a_kg, e.scatter_b
    )
