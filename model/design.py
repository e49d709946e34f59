"""Adaptive design of a joint-estimation series: which distance next, and when to stop (pure).

The model is `m = k / l` with slip masses scattered as sd(m)² = a² + (b·m)² (`model.k_estimators`).
One trial at distance l then carries the Fisher information I(l) = 1 / (a²·l² + (b·k)²) on k: with
additive or mixed scatter (a > 0) short distances carry more, with purely multiplicative scatter
(a = 0) every distance carries the same. The 99 % bound's half-width is about t·(Σ I)^(-1/2), so the
trial that most shrinks it is the one with the largest I(l) among the distances that are safe.

`plan_next` turns the data of a series so far into one `DesignStep`:

1. **Estimate**: k and the scatter come in from the caller, normally `current_estimate` (the
   series' estimator through `model.k_estimators.estimate_k`).
2. **Lack of fit** of the 1/l law (`lack_of_fit`), reported after every trial: a weighted
   pure-error F test once distances are repeated, else a t test of an offset c in m = k/l + c.
3. **Stop** when the bound's half-width is at most `target_half_width_rel` of k even with the
   scatter's scale at its upper `stop_scale_confidence` confidence limit (`stop_half_width_rel`;
   after at least `min_trials` trials), or at `max_trials`, or when no candidate distance is safe.
   Why the upper limit: the bound stopped on comes from the data that said stop. A series whose
   scatter looks small by chance would otherwise stop early, with a bound whose width is the
   target but whose true standard error is larger than the estimate says (optional stopping),
   and the stopped bounds would cover the truth less often than a fixed design's. Asking that the
   target hold for every scale the data leave plausible at that confidence (chi-square on the
   bound's degrees of freedom) makes such early stops rare; the bound reported is still the
   estimator's own. studies/adaptive_design.py measures the coverage at the stop per scatter shape:
   with `auto`'s bounds it is the fixed design's already at confidence 0 (the default), so the
   allowance is an option a protocol may take, paid in trials.
4. **Candidates**: `distance_count` distances evenly over `distance_range_m`, keeping only those
   longer than every distance that gave no slip (a lower bound on the force there) and whose
   predicted slip force stays below `max_slip_force_n`: k's upper estimate k + 3·se, plus three
   sd of one trial's scatter, times g / l. Before a fit (fewer than 2 slips) the largest m·l seen
   stands for k with `PRIOR_RELATIVE_SD` as its scatter.
5. **Start-up**: the first `startup_trials` spread over the range from the longest distance to the
   shortest (the order in which the force rises), each replaced by the shortest safe distance
   when it is not safe.
6. **Adaptive**: a distance in the upper half of the range whenever fewer than `min_spread_fraction`
   of the slips lie there (the lack-of-fit test needs spread); otherwise, among the candidates
   within `NEAR_BEST_INFORMATION` of the most informative, the one with the fewest trials so far
   (ties: the longer). Under multiplicative scatter all are near-best, so the series spreads evenly;
   under additive scatter only the shortest safe distances are.

Deterministic: the same data give the same step (a resumed run replans from its journal).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Final

import numpy as np

from model.fit import DEFAULT_LEVEL, check_level, t_quantile
from model.k_estimators import EstimatorName, KEstimate, check_estimator, estimate_k

NEAR_BEST_INFORMATION: Final = 0.9  # a candidate within 10 % of the best information per trial is "near best"
PRIOR_RELATIVE_SD: Final = 0.25  # scatter of m·l assumed before a fit, for the force filter only
PREDICTION_SIGMAS: Final = 3.0  # how far above the estimate the force filter looks
LACK_OF_FIT_ALPHA: Final = 0.01  # the 1/l law is reported as rejected below this p-value
# Defaults of a design block; studies/adaptive_design.py measured them (studies/README.md). The
# stopping rule's confidence that the scatter is no larger than the scale it assumes is 0 (the
# estimate itself): with `auto`'s bounds the coverage at the stop is already the fixed design's,
# and 0.95 cost up to 10 more trials. Three start-up trials and 10 % of the slips in the upper half
# keep the 1/l law well testable; 2 and 5 % (protocols/joint_estimation_adaptive.yaml) keep it
# testable (two distances with replicates) and save a trial under mixed scatter.
DEFAULT_STOP_SCALE_CONFIDENCE: Final = 0.0
DEFAULT_STARTUP_TRIALS: Final = 3
DEFAULT_MIN_SPREAD_FRACTION: Final = 0.1
_DISTANCE_DIGITS: Final = 9  # distances equal to 1 nm are the same distance (replicates)


class StopReason(StrEnum):
    """Why a series stopped."""

    TARGET_REACHED = "target_reached"
    BUDGET = "budget"
    NO_SAFE_DISTANCE = "no_safe_distance"


class Choice(StrEnum):
    """Why the next distance was chosen."""

    STARTUP = "startup"
    INFORMATIVE = "informative"
    SPREAD = "spread"


@dataclass(frozen=True, slots=True)
class DesignSettings:
    """An adaptive series as the protocol states it (SI units; see the module docstring)."""

    distance_min_m: float
    distance_max_m: float
    distance_count: int = 8
    target_half_width_rel: float = 0.02
    max_trials: int = 24
    min_trials: int = 10
    startup_trials: int = DEFAULT_STARTUP_TRIALS
    min_spread_fraction: float = DEFAULT_MIN_SPREAD_FRACTION
    estimator: EstimatorName = "auto"
    level: float = DEFAULT_LEVEL
    stop_scale_confidence: float = DEFAULT_STOP_SCALE_CONFIDENCE

    def __post_init__(self) -> None:
        """Reject settings the planner cannot work with (the protocol reader gives nicer messages)."""
        if not (0 < self.distance_min_m < self.distance_max_m and math.isfinite(self.distance_max_m)):
            raise ValueError(
                f"distance range [{self.distance_min_m}, {self.distance_max_m}] m; allowed: 0 < min < max"
            )
        if self.distance_count < 2:
            raise ValueError(f"distance_count {self.distance_count}; allowed: at least 2")
        if not 0 < self.target_half_width_rel < 1:
            raise ValueError(f"target_half_width_rel {self.target_half_width_rel}; allowed: (0, 1)")
        if not 2 <= self.startup_trials <= self.max_trials or not 2 <= self.min_trials <= self.max_trials:
            raise ValueError(
                f"startup_trials {self.startup_trials}, min_trials {self.min_trials}, max_trials "
                f"{self.max_trials}; allowed: 2 <= startup_trials, min_trials <= max_trials"
            )
        if not 0 <= self.min_spread_fraction <= 0.5:
            raise ValueError(f"min_spread_fraction {self.min_spread_fraction}; allowed: [0, 0.5]")
        if not 0 <= self.stop_scale_confidence < 1:
            raise ValueError(f"stop_scale_confidence {self.stop_scale_confidence}; allowed: [0, 1)")
        check_estimator(self.estimator)
        check_level(self.level)

    @property
    def candidates_m(self) -> tuple[float, ...]:
        """Every distance the planner may choose, shortest first."""
        grid = np.linspace(self.distance_min_m, self.distance_max_m, self.distance_count)
        return tuple(round(float(d), _DISTANCE_DIGITS) for d in grid)

    @property
    def startup_m(self) -> tuple[float, ...]:
        """The start-up distances as planned (before the force filter), longest first."""
        grid = self.candidates_m
        picks = np.linspace(len(grid) - 1, 0, self.startup_trials)
        return tuple(grid[round(float(i))] for i in picks)

    @property
    def spread_from_m(self) -> float:
        """Distances at least this long count as spread (the upper half of the range)."""
        return 0.5 * (self.distance_min_m + self.distance_max_m)


@dataclass(frozen=True, slots=True)
class Observation:
    """One finished trial of the series: a slip mass, or (censored) the mass the ramp reached without one."""

    distance_m: float
    mass_kg: float
    censored: bool = False


@dataclass(frozen=True, slots=True)
class LackOfFit:
    """A test of the 1/l law over the slips so far; `test` is "none" while the data cannot test it."""

    test: str  # "pure_error_f", "offset_t" or "none"
    statistic: float  # F, or |t|; NaN for "none"
    df: tuple[int, int]  # (numerator, denominator) for F; (0, n - 2) for t
    p_value: float  # NaN for "none"
    distinct_distances: int

    @property
    def rejected(self) -> bool:
        """Whether the data contradict m = k/l at the `LACK_OF_FIT_ALPHA` level."""
        return self.p_value < LACK_OF_FIT_ALPHA  # False for NaN

    def text(self) -> str:
        """One line for the log."""
        if self.test == "none":
            return f"lack of fit: not testable yet ({self.distinct_distances} distance(s))"
        name = (
            f"F({self.df[0]}, {self.df[1]})" if self.test == "pure_error_f" else f"offset |t|({self.df[1]})"
        )
        verdict = "1/l law REJECTED" if self.rejected else "consistent with 1/l"
        return f"lack of fit: {name} = {self.statistic:.3g}, p = {self.p_value:.3g} ({verdict})"


@dataclass(frozen=True, slots=True)
class DesignStep:
    """The planner's answer after the trials so far: the next distance, or why the series stops."""

    trials_done: int
    estimate: KEstimate | None
    half_width_rel: float | None  # of the current bound, relative to k
    stop_half_width_rel: float | None  # the same with the scale at its upper limit: what the stop tests
    lack_of_fit: LackOfFit
    next_distance_m: float | None  # None when stopping
    choice: Choice | None
    expected_half_width_rel: float | None  # after the next trial, under the fitted scatter
    stop: StopReason | None
    safe_candidates_m: tuple[float, ...]

    def text(self, settings: DesignSettings) -> str:
        """One line for the log and the progress display."""
        est = self.estimate
        now = "no fit yet"
        if est is not None and self.half_width_rel is not None:
            now = (
                f"k {est.k:.5g} kg·m ({est.estimator}, {est.scatter_model}), half-width "
                f"{100 * self.half_width_rel:.2f} %"
                + (
                    f" ({100 * (self.stop_half_width_rel or math.inf):.2f} % at the scatter's upper limit)"
                    if settings.stop_scale_confidence > 0
                    else ""
                )
                + f"; target {100 * settings.target_half_width_rel:g} %"
            )
        if self.stop is not None:
            what = {
                StopReason.TARGET_REACHED: "target reached",
                StopReason.BUDGET: f"trial budget of {settings.max_trials} used",
                StopReason.NO_SAFE_DISTANCE: "no distance is safe within the force limits",
            }[self.stop]
            head = f"stopped after {self.trials_done} trial(s): {what}"
        else:
            assert self.next_distance_m is not None and self.choice is not None
            head = f"after {self.trials_done} trial(s): next {self.next_distance_m:.4f} m ({self.choice})"
        return f"{head}; {now}; {self.lack_of_fit.text()}"


def information_per_trial(distance_m: float, k: float, scatter_a_kg: float, scatter_b: float) -> float:
    """Fisher information on k of one slip at `distance_m` under sd(m)² = a² + (b·m)² [1/(kg·m)²]."""
    variance = (scatter_a_kg * distance_m) ** 2 + (scatter_b * k) ** 2
    floor = (1e-9 * abs(k)) ** 2 or 1e-300  # exact data: every distance equal, not infinite
    return 1.0 / max(variance, floor)


def lack_of_fit(
    distances_m: Sequence[float], masses_kg: Sequence[float], scatter_a_kg: float, scatter_b: float, k: float
) -> LackOfFit:
    """Test m = k/l over slips, each weighted by 1/sd(m)² of the fitted scatter.

    With replicates (more slips than distinct distances, at least 2 distances): the pure-error F test
    (the weighted residual of the 1/l fit beyond the scatter within each distance). Otherwise, with
    at least 3 slips at 2 or more distances: the t test of c in the weighted fit m = k/l + c.
    """
    from scipy import stats  # as model.fit: imported on first use

    ls = np.asarray(distances_m, dtype=float)
    ms = np.asarray(masses_kg, dtype=float)
    keys = np.round(ls, _DISTANCE_DIGITS)
    groups = np.unique(keys)
    g, n = len(groups), len(ls)
    none = LackOfFit("none", math.nan, (0, 0), math.nan, g)
    if g < 2 or n < 3:
        return none
    expected = np.abs(k) / ls
    variance = scatter_a_kg**2 + (scatter_b * expected) ** 2
    w = 1.0 / np.maximum(variance, (1e-9 * expected) ** 2 + 1e-300)
    x = 1.0 / ls
    if n - g >= 1:
        k_w = float(np.sum(w * x * ms) / np.sum(w * x * x))
        sse = float(np.sum(w * (ms - k_w * x) ** 2))
        pure = 0.0
        for key in groups:
            sel = keys == key
            mean = float(np.sum(w[sel] * ms[sel]) / np.sum(w[sel]))
            pure += float(np.sum(w[sel] * (ms[sel] - mean) ** 2))
        if pure > 0.0:
            df1, df2 = g - 1, n - g
            f = max(sse - pure, 0.0) / df1 / (pure / df2)
            return LackOfFit("pure_error_f", f, (df1, df2), float(stats.f.sf(f, df1, df2)), g)
    design = np.column_stack([x, np.ones_like(x)]) * np.sqrt(w)[:, None]
    target = ms * np.sqrt(w)
    coef, *_ = np.linalg.lstsq(design, target, rcond=None)
    resid = target - design @ coef
    dof = n - 2
    s2 = float(resid @ resid) / dof
    cov = s2 * np.linalg.inv(design.T @ design)
    se_c = math.sqrt(max(float(cov[1, 1]), 0.0))
    if not se_c > 0.0:
        return none
    t = abs(float(coef[1])) / se_c
    return LackOfFit("offset_t", t, (0, dof), float(2.0 * stats.t.sf(t, dof)), g)


def current_estimate(settings: DesignSettings, observations: Sequence[Observation]) -> KEstimate | None:
    """The estimate of k by the series' estimator, or None before it can fit (fewer than 2 slips)."""
    slips = [o for o in observations if not o.censored]
    if len(slips) < 2:
        return None
    try:
        return estimate_k(
            settings.estimator,
            [o.distance_m for o in observations],
            [o.mass_kg for o in observations],
            [o.censored for o in observations],
            settings.level,
        )
    except ValueError:  # e.g. the weighted estimate of slips that all sit at one product: no fit yet
        return None


def predicted_slip_mass_kg(
    distance_m: float, estimate: KEstimate | None, observations: Sequence[Observation]
) -> float:
    """A high guess of the slip mass at `distance_m`: what the force filter holds against the limit."""
    if estimate is not None and math.isfinite(estimate.se):
        k_high = abs(estimate.k) + PREDICTION_SIGMAS * estimate.se
        mass = k_high / distance_m
        spread = math.hypot(estimate.scatter_a_kg, estimate.scatter_b * mass)
        return mass + PREDICTION_SIGMAS * spread
    products = [o.distance_m * o.mass_kg for o in observations]
    if not products:
        return math.inf  # nothing known: only the longest distance is tried (see safe_candidates)
    return max(products) / distance_m * (1.0 + PREDICTION_SIGMAS * PRIOR_RELATIVE_SD)


def safe_candidates(
    settings: DesignSettings,
    observations: Sequence[Observation],
    estimate: KEstimate | None,
    max_slip_force_n: float,
    g: float,
) -> tuple[float, ...]:
    """The candidate distances whose predicted slip force stays below `max_slip_force_n`, shortest first.

    A distance at or below one that gave no slip is never safe (the force there is higher still).
    Before any trial only the longest distance is offered.
    """
    grid = settings.candidates_m
    if not observations:
        return grid[-1:]
    no_slip = max((o.distance_m for o in observations if o.censored), default=0.0)
    return tuple(
        d
        for d in grid
        if d > no_slip + 10.0**-_DISTANCE_DIGITS
        and predicted_slip_mass_kg(d, estimate, observations) * g <= max_slip_force_n
    )


def half_width_rel(estimate: KEstimate) -> float:
    """Half the width of the estimate's bound, relative to |k| (inf for k = 0)."""
    lo, hi = estimate.k_ci
    return 0.5 * (hi - lo) / abs(estimate.k) if estimate.k != 0 else math.inf


def scale_upper_factor(dof: int, confidence: float) -> float:
    """How many times its estimate the scatter's scale may be at `confidence` (chi-square, `dof` df).

    sqrt(dof / q) with q the (1 - confidence) quantile of chi-square on `dof` degrees of freedom;
    1 for confidence 0, inf without degrees of freedom.
    """
    if confidence == 0:
        return 1.0
    if dof < 1:
        return math.inf
    from scipy import stats  # as model.fit: imported on first use

    return math.sqrt(dof / float(stats.chi2.ppf(1.0 - confidence, dof)))


def stop_half_width_rel(settings: DesignSettings, estimate: KEstimate) -> float:
    """The relative half-width the stopping rule tests: the bound's, with the scale at its upper limit.

    The degrees of freedom are the bound's own (n - 1, as its t quantile).
    """
    return half_width_rel(estimate) * scale_upper_factor(estimate.n - 1, settings.stop_scale_confidence)


def plan_next(
    settings: DesignSettings,
    observations: Sequence[Observation],
    estimate: KEstimate | None,
    *,
    max_slip_force_n: float,
    g: float,
) -> DesignStep:
    """The next trial's distance after `observations` (in the order run), or the reason to stop.

    `estimate` is the current estimate of k from those observations (`current_estimate`, or None
    before a fit); its bounds drive the stopping rule and its fitted scatter the choice.
    """
    n = len(observations)
    slips = [o for o in observations if not o.censored]
    width = half_width_rel(estimate) if estimate is not None else None
    stop_width = stop_half_width_rel(settings, estimate) if estimate is not None else None
    if estimate is not None:
        test = lack_of_fit(
            [o.distance_m for o in slips],
            [o.mass_kg for o in slips],
            estimate.scatter_a_kg,
            estimate.scatter_b,
            estimate.k,
        )
    else:
        test = LackOfFit("none", math.nan, (0, 0), math.nan, len({o.distance_m for o in slips}))
    safe = safe_candidates(settings, observations, estimate, max_slip_force_n, g)

    def step(
        stop: StopReason | None,
        distance: float | None = None,
        choice: Choice | None = None,
        expected: float | None = None,
    ) -> DesignStep:
        return DesignStep(n, estimate, width, stop_width, test, distance, choice, expected, stop, safe)

    if n >= settings.max_trials:
        return step(StopReason.BUDGET)
    if n >= settings.min_trials and stop_width is not None and stop_width <= settings.target_half_width_rel:
        return step(StopReason.TARGET_REACHED)
    if not safe:
        return step(StopReason.NO_SAFE_DISTANCE)
    if n < settings.startup_trials:
        planned = settings.startup_m[n]
        distance = planned if planned in safe else safe[0]
        return step(None, distance, Choice.STARTUP, _expected_width(settings, slips, estimate, distance))
    spread = sum(1 for o in slips if o.distance_m >= settings.spread_from_m)
    far = [d for d in safe if d >= settings.spread_from_m]
    if far and spread < settings.min_spread_fraction * (len(slips) + 1):
        distance = _least_used(far, observations)
        return step(None, distance, Choice.SPREAD, _expected_width(settings, slips, estimate, distance))
    if estimate is None:
        info = dict.fromkeys(safe, 1.0)
    else:
        info = {
            d: information_per_trial(d, estimate.k, estimate.scatter_a_kg, estimate.scatter_b) for d in safe
        }
    best = max(info.values())
    near = [d for d in safe if info[d] >= NEAR_BEST_INFORMATION * best]
    distance = _least_used(near, observations)
    return step(None, distance, Choice.INFORMATIVE, _expected_width(settings, slips, estimate, distance))


def _least_used(distances: Sequence[float], observations: Sequence[Observation]) -> float:
    """The distance with the fewest trials so far; ties go to the longer one (lower force)."""
    counts = {d: 0 for d in distances}
    for o in observations:
        key = round(o.distance_m, _DISTANCE_DIGITS)
        if key in counts:
            counts[key] += 1
    return min(distances, key=lambda d: (counts[d], -d))


def _expected_width(
    settings: DesignSettings, slips: Sequence[Observation], estimate: KEstimate | None, distance_m: float
) -> float | None:
    """The bound's relative half-width after one more slip at `distance_m`, under the fitted scatter."""
    if estimate is None or estimate.k == 0:
        return None
    k, a, b = estimate.k, estimate.scatter_a_kg, estimate.scatter_b
    total = sum(information_per_trial(o.distance_m, k, a, b) for o in slips)
    total += information_per_trial(distance_m, k, a, b)
    return t_quantile(settings.level, len(slips)) / math.sqrt(total) / abs(k)
