"""The adaptive design (`model.design`) against the fixed 0.03-0.25 m x 8 x 3 design, at model level.

Bare statistics, no rig: slip masses m = k/l · (1 + b·e1) + a·e2 (e1, e2 standard normal) for
k = 0.1615 kg·m under each scatter shape below. `additive`, `multiplicative` and `mixed` are the
simulated rig's scenarios (a and b read from their configs by `scatter_shapes.py`); the others are
study-only shapes. Per shape and seed:

* fixed: the 24 trials of 8 distances evenly over 0.03-0.25 m x 3, fitted by `--estimator`;
* adaptive: `model.design.plan_next` chooses every distance from the same candidate grid
  (no force limit here) until its stopping rule says stop, with the target half-width set to the
  median half-width of the fixed design for that shape (so both reach the same bound width) and
  the fixed design's 24 trials as the budget.

Floors (the columns "floor"): the fewest trials that reach the target with the efficient estimate
and a t interval if every trial were at one distance: 0.03 m (the protocol's shortest), the
shortest distance the built-in rig's force limits allow any protocol (the ceiling times the
largest `max_force_fraction`, at the true k), and l -> 0 (no design, at any force, does better:
only the proportional part of the scatter is left). A design that starts spread over the range
cannot beat them; where the l -> 0 floor exceeds 0.6 x 24, no design reaches the issue's 0.6x.

Printed per shape: the fixed design's median half-width, the adaptive run's median trials (and
their ratio to 24), how often it reached the target within the budget, and the coverage of the
true k by the 99 % bounds for both (with 95 % Clopper-Pearson intervals). The shape
`multiplicative-tight` draws data with half the planned scatter against the target of
`multiplicative`: there the stopping rule alone saves trials.

    .venv/bin/python studies/adaptive_design.py [--estimator auto] [--seeds 200] [--first-seed 0]
        [--stop-confidence 0.75] [--shapes additive,mixed,...]
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, replace

import numpy as np
from scatter_shapes import scenario_shapes
from scipy import stats

from model import k_estimators as estimators
from model.design import (
    DEFAULT_MIN_SPREAD_FRACTION,
    DEFAULT_STARTUP_TRIALS,
    DEFAULT_STOP_SCALE_CONFIDENCE,
    DesignSettings,
    Observation,
    StopReason,
    current_estimate,
    half_width_rel,
    information_per_trial,
    plan_next,
)
from model.fit import t_quantile
from model.k_estimators import ESTIMATOR_NAMES, KEstimate, check_estimator, estimate_k
from rig.inputs.rig_config import load_rig_config
from rig.study.statistics import clopper_pearson

K_TRUE = 0.1615  # link 1 of the paper [kg·m]
G = 9.8
# The largest share of the force limit a protocol may let the planner aim at (rig/inputs/protocol.py's
# upper limit of max_force_fraction), for the force-limited floor.
MAX_FORCE_FRACTION_ALLOWED = 0.95
RANGE_M = (0.03, 0.25)
FIXED_DISTANCES_M = np.linspace(*RANGE_M, 8)
FIXED_REPEATS = 3
LEVEL = 0.99
# Not a project estimator: weighted least squares with the true shape of the scatter (the ratio of a
# to b) and its level estimated from the residuals, with a t interval on n - 1 degrees of freedom.
# What the planner achieves when the scatter model it is given is right.
ORACLE = "oracle-shape"


@dataclass(frozen=True)
class Shape:
    """A scatter shape, sd(m)² = a² + (b·m)², and the shape whose fixed design sets its target."""

    a_kg: float
    b: float
    target_from: str | None = None  # another shape's fixed-design width (None: this one's)
    note: str = ""


def study_shapes() -> dict[str, Shape]:
    """The shapes studied: the simulator's scenarios (from their configs) and three study-only ones."""
    rig = scenario_shapes()
    add, mul, mix = rig["additive"], rig["multiplicative"], rig["mixed"]
    return {
        "additive": Shape(add.a_kg, add.b, note=f"the additive scenario ({add.source})"),
        "mixed": Shape(mix.a_kg, mix.b, note=f"the mixed scenario ({mix.source})"),
        "mixed-additive": Shape(0.11, 0.03, note="mostly additive: 3 % capacity scatter plus 0.11 kg"),
        "mixed-paper": Shape(0.089, 0.06, note="the former study's mixed: half the paper's RMSE as variance"),
        "multiplicative": Shape(mul.a_kg, mul.b, note=f"the built-in rig ({mul.source})"),
        "multiplicative-tight": Shape(0.0, mul.b / 2, "multiplicative", "half the planned scatter"),
    }


def masses(rng: np.random.Generator, distances_m: np.ndarray, shape: Shape) -> np.ndarray:
    """Slip masses at `distances_m` under `shape`."""
    mean = K_TRUE / distances_m
    e1, e2 = rng.standard_normal((2, len(distances_m)))
    return mean * (1.0 + shape.b * e1) + shape.a_kg * e2


def covers(estimate: KEstimate) -> bool:
    """Whether the estimate's bounds hold the true k."""
    return estimate.k_ci[0] <= K_TRUE <= estimate.k_ci[1]


def oracle_estimate(distances_m: np.ndarray, masses_kg: np.ndarray, shape: Shape) -> KEstimate:
    """See `ORACLE`: weights 1/sd(m)² from the true shape, the scale fitted."""
    x = 1.0 / distances_m
    w = 1.0 / (shape.a_kg**2 + (shape.b * K_TRUE * x) ** 2)
    info = float(np.sum(w * x * x))
    k = float(np.sum(w * x * masses_kg)) / info
    n = len(x)
    scale2 = float(np.sum(w * (masses_kg - k * x) ** 2)) / (n - 1)
    se = math.sqrt(scale2 / info)
    half = t_quantile(LEVEL, n - 1) * se
    scale = math.sqrt(scale2)
    model = "mixed" if shape.a_kg and shape.b else ("additive" if shape.a_kg else "multiplicative")
    return KEstimate(
        "auto", model, n, 0, k, (k - half, k + half), se, LEVEL, shape.a_kg * scale, shape.b * scale
    )


def estimate(estimator: str, distances_m: np.ndarray, masses_kg: np.ndarray, shape: Shape) -> KEstimate:
    """The named estimator's estimate (a project estimator, or `ORACLE`)."""
    if estimator == ORACLE:
        return oracle_estimate(distances_m, masses_kg, shape)
    return estimate_k(check_estimator(estimator), distances_m, masses_kg, None, LEVEL)


def fixed_runs(estimator: str, shape: Shape, seeds: range) -> tuple[list[float], list[bool]]:
    """Half-widths (relative) and coverage of the fixed design, one per seed."""
    distances = np.repeat(FIXED_DISTANCES_M, FIXED_REPEATS)
    widths, hits = [], []
    for seed in seeds:
        rng = np.random.default_rng([seed, 0])
        est = estimate(estimator, distances, masses(rng, distances, shape), shape)
        widths.append(half_width_rel(est))
        hits.append(covers(est))
    return widths, hits


@dataclass(frozen=True)
class AdaptiveRun:
    """One adaptive series: trials used, why it stopped, and its final estimate."""

    trials: int
    stop: StopReason
    estimate: KEstimate | None
    short_share: float  # share of the trials at the shortest distance
    distances_m: tuple[float, ...]  # in the order run


def adaptive_run(estimator: str, settings: DesignSettings, shape: Shape, seed: int) -> AdaptiveRun:
    """Run the planner's loop on synthetic data until it stops."""
    rng = np.random.default_rng([seed, 1])
    observations: list[Observation] = []
    while True:
        if estimator == ORACLE:
            ls = np.array([o.distance_m for o in observations])
            ms = np.array([o.mass_kg for o in observations])
            current = oracle_estimate(ls, ms, shape) if len(observations) >= 2 else None
        else:
            current = current_estimate(settings, observations)
        step = plan_next(settings, observations, current, max_slip_force_n=math.inf, g=G)
        if step.stop is not None:
            shortest = sum(1 for o in observations if o.distance_m == settings.candidates_m[0])
            distances = tuple(o.distance_m for o in observations)
            return AdaptiveRun(
                len(observations), step.stop, step.estimate, shortest / len(observations), distances
            )
        assert step.next_distance_m is not None
        mass = float(masses(rng, np.array([step.next_distance_m]), shape)[0])
        observations.append(Observation(step.next_distance_m, mass))


def split_coverage(estimator: str, shape: Shape, runs: list[AdaptiveRun], seeds: range) -> str:
    """Coverage of the series that stopped on the target and of the others; and with fresh data.

    The last: each series' own distances refitted on data drawn anew (no stopping, no choice of
    distance depended on them), which separates what the stop does from what the design does.
    """
    stopped = [r for r in runs if r.stop is StopReason.TARGET_REACHED]
    others = [r for r in runs if r.stop is not StopReason.TARGET_REACHED]

    def share(group: list[AdaptiveRun]) -> str:
        hits = sum(r.estimate is not None and covers(r.estimate) for r in group)
        return f"{100 * hits / len(group):.1f} % of {len(group)}" if group else "none"

    fresh = 0
    for run, seed in zip(runs, seeds, strict=True):
        rng = np.random.default_rng([seed, 2])
        distances = np.array(run.distances_m)
        fresh += covers(estimate(estimator, distances, masses(rng, distances, shape), shape))
    return f"{share(stopped)} / {share(others)} / {100 * fresh / len(runs):.1f} %"


def floor_trials(shape: Shape, target_half_width_rel: float, distance_m: float) -> int:
    """Fewest trials that reach the target if every one were at `distance_m` (efficient estimate, t interval).

    The bound of any design that starts spread and keeps some spread is wider: a floor, not a goal.
    `distance_m` 0 gives the floor of every design: only the proportional scatter is left.
    """
    info = information_per_trial(distance_m, K_TRUE, shape.a_kg, shape.b)
    for n in range(2, 10_000):
        if t_quantile(LEVEL, n - 1) / math.sqrt(n * info) / K_TRUE <= target_half_width_rel:
            return n
    return 10_000


def known_scatter_trials(settings: DesignSettings, shape: Shape) -> int:
    """Trials the planner needs when it knows k and the scatter exactly (exact data, efficient bound).

    Its own design (start-up, spread, the most informative distances), stopped as soon as the
    efficient t bound reaches the target: what the start-up and the spread cost on top of the floors,
    before any estimation or stopping noise.
    """
    known = replace(settings, min_trials=2, max_trials=1000, stop_scale_confidence=0.0)
    model = "mixed" if shape.a_kg and shape.b else ("additive" if shape.a_kg else "multiplicative")
    observations: list[Observation] = []
    while True:
        current = None
        if len(observations) >= 2:
            info = sum(information_per_trial(o.distance_m, K_TRUE, shape.a_kg, shape.b) for o in observations)
            se = 1.0 / math.sqrt(info)
            half = t_quantile(LEVEL, len(observations) - 1) * se
            current = KEstimate(
                "auto",
                model,
                len(observations),
                0,
                K_TRUE,
                (K_TRUE - half, K_TRUE + half),
                se,
                LEVEL,
                shape.a_kg,
                shape.b,
            )
        step = plan_next(known, observations, current, max_slip_force_n=math.inf, g=G)
        if step.stop is not None or step.next_distance_m is None:
            return len(observations)
        observations.append(Observation(step.next_distance_m, K_TRUE / step.next_distance_m))


def shortest_reachable_m() -> float:
    """The shortest distance whose slip force (at the true k) the built-in rig lets any protocol reach."""
    config = load_rig_config(None)
    return K_TRUE * G / (MAX_FORCE_FRACTION_ALLOWED * config.limits.force_ceiling_n)


def percent(hits: int, n: int) -> str:
    lo, hi = clopper_pearson(hits, n)
    return f"{100 * hits / n:5.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]"


def main() -> None:
    shapes = study_shapes()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--estimator",
        default="auto",
        choices=(*ESTIMATOR_NAMES, ORACLE),
        help=f"the estimator of both designs (default auto); {ORACLE}: see ORACLE in the script",
    )
    parser.add_argument("--seeds", type=int, default=200, help="seeds per shape (default 200)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument(
        "--shapes", default=",".join(shapes), help="comma-separated, of: " + ", ".join(shapes)
    )
    parser.add_argument("--min-trials", type=int, default=10)
    parser.add_argument("--startup-trials", type=int, default=DEFAULT_STARTUP_TRIALS)
    parser.add_argument("--min-spread-fraction", type=float, default=DEFAULT_MIN_SPREAD_FRACTION)
    parser.add_argument(
        "--stop-confidence",
        type=float,
        default=DEFAULT_STOP_SCALE_CONFIDENCE,
        help="the stopping rule's stop_scale_confidence (model/design.py; 0: stop on the bound itself)",
    )
    args = parser.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    budget = len(FIXED_DISTANCES_M) * FIXED_REPEATS
    shortest_m = shortest_reachable_m()
    started = time.perf_counter()
    print(
        f"estimator {args.estimator} ({estimators.__name__}: {estimators.__doc__.splitlines()[0]}); "
        f"{args.seeds} seeds per shape (from {args.first_seed}); k = {K_TRUE} kg·m; "
        f"fixed design {RANGE_M[0]}-{RANGE_M[1]} m x 8 x 3 = {budget} trials; adaptive budget {budget}, "
        f"min_trials {args.min_trials}, startup_trials {args.startup_trials}, "
        f"min_spread_fraction {args.min_spread_fraction}, stop_scale_confidence {args.stop_confidence}; "
        f"shortest distance the rig's force limits allow: {1000 * shortest_m:.1f} mm"
    )
    targets: dict[str, float] = {}
    verdicts: list[str] = []
    header = (
        "| shape | a [kg] | b | fixed: median half-width | fixed: coverage | adaptive: median trials "
        f"(x fixed; quartiles; max) | floor: all at 0.03 m / {1000 * shortest_m:.0f} mm / l -> 0 "
        "| planner, scatter known "
        "| reached target | trials at 0.03 m | adaptive: coverage | coverage: stopped on target / "
        "the others / fresh data on the same distances | scatter model at stop |"
    )
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    for name in args.shapes.split(","):
        shape = shapes[name]
        if shape.target_from and shape.target_from not in targets:
            targets[shape.target_from] = float(
                np.median(fixed_runs(args.estimator, shapes[shape.target_from], seeds)[0])
            )
        widths, fixed_hits = fixed_runs(args.estimator, shape, seeds)
        targets[name] = float(np.median(widths))
        target = targets[shape.target_from] if shape.target_from else targets[name]
        settings = DesignSettings(
            *RANGE_M,
            distance_count=len(FIXED_DISTANCES_M),
            target_half_width_rel=target,
            max_trials=budget,
            min_trials=args.min_trials,
            startup_trials=args.startup_trials,
            min_spread_fraction=args.min_spread_fraction,
            estimator="auto" if args.estimator == ORACLE else check_estimator(args.estimator),
            level=LEVEL,
            stop_scale_confidence=args.stop_confidence,
        )
        runs = [adaptive_run(args.estimator, settings, shape, seed) for seed in seeds]
        trials = [r.trials for r in runs]
        median = float(np.median(trials))
        reached = sum(r.stop is StopReason.TARGET_REACHED for r in runs)
        hits = sum(r.estimate is not None and covers(r.estimate) for r in runs)
        models: dict[str, int] = {}
        for r in runs:
            key = r.estimate.scatter_model if r.estimate is not None else "none"
            models[key] = models.get(key, 0) + 1
        floors = [floor_trials(shape, target, d) for d in (RANGE_M[0], shortest_m, 0.0)]
        target_note = f" (target: {shape.target_from}'s {100 * target:.2f} %)" if shape.target_from else ""
        print(
            f"| {name} | {shape.a_kg:g} | {shape.b:g} | {100 * float(np.median(widths)):.2f} %"
            f"{target_note} | {percent(sum(fixed_hits), len(seeds))} | {median:g} ({median / budget:.2f}; "
            f"{np.percentile(trials, 25):g}-{np.percentile(trials, 75):g}; {max(trials)}) | "
            f"{' / '.join(str(f) for f in floors)} | {known_scatter_trials(settings, shape)} | "
            f"{percent(reached, len(seeds))} | "
            f"{100 * float(np.mean([r.short_share for r in runs])):.0f} % | {percent(hits, len(seeds))} | "
            f"{split_coverage(args.estimator, shape, runs, seeds)} | "
            f"{', '.join(f'{k} {v}' for k, v in sorted(models.items()))} |"
        )
        if name.startswith(("additive", "mixed")):
            verdicts.append(
                f"{name}: median {median:g} trials <= 0.6 x {budget}: {median <= 0.6 * budget} "
                f"(no design below {floors[2]}, none within the rig's force limits below {floors[1]})"
            )
        elif name == "multiplicative":
            verdicts.append(f"{name}: never more than {budget} trials: {max(trials) <= budget}")
        else:
            verdicts.append(
                f"{name}: the stopping rule saves trials (median {median:g} < {budget}): {median < budget}"
            )
        fixed_hit_count = sum(fixed_hits)
        # Two independent samples of series (the adaptive ones draw their own data): Fisher's exact test.
        p_value = float(
            stats.fisher_exact(
                [[hits, len(seeds) - hits], [fixed_hit_count, len(seeds) - fixed_hit_count]]
            ).pvalue
        )
        verdicts.append(
            f"{name}: coverage {100 * hits / len(seeds):.1f} % adaptive vs "
            f"{100 * fixed_hit_count / len(seeds):.1f} % fixed (Fisher's exact test p = {p_value:.2f})"
        )
    print("targets (issue 12):")
    for verdict in verdicts:
        print(f"  {verdict}")
    print(f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
