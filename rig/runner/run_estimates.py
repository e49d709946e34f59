"""The run's estimates: the joint-estimation fit, per-joint capacities, and predictions.

Glue between the runner and `model/`: it feeds each finished trial into the pure functions
(`model.online_fit` for the paper's fit, `model.fit_keys` for the protocol's estimator,
`model.capacity_grid_filter`), predicts the next trial's slip load from the estimates **the rig
itself made** (never from simulator truth), and gives the estimate as one
`rig.records.Estimate` for the log, the progress line and the report. Slips feed the fit; a
joint-estimation trial that ended without a slip enters it as a lower bound on the slip mass
(censored; the paper's fit leaves it out). Replaying the same results rebuilds the same state,
which is how `--resume` restores it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from statistics import NormalDist
from typing import Any, assert_never

import numpy as np

from model.capacity_grid_filter import (
    DEFAULT_OBS_SD_LOG,
    LinkEstimatorState,
    PerJointEstimates,
    link_estimator_estimates,
    link_estimator_init,
    link_estimator_update,
)
from model.chain import planar_transforms, predict_slip
from model.fit import FitSummary, capacity_from_fit, fit_summary
from model.fit_keys import EstimateSummary, summarize_estimate
from model.k_estimators import DEFAULT_ESTIMATOR, EstimatorName
from model.online_fit import online_fit_estimate, online_fit_init, online_fit_update
from rig.errors import InputError
from rig.inputs.files import load_json_file
from rig.inputs.rig_config import ArticleConfig
from rig.records import Estimate, JointCapacity, TrialKind, TrialOutcome, TrialResult

# How much the joints of one link are taken to differ from the joint that was fitted (log sd):
# the paper assumed identical joints; 10 % is the spread a hand-made link plausibly has.
BETWEEN_JOINT_SD_LOG = 0.10
# The per-joint filter's trial-to-trial scatter is the upper bound of this one-sided confidence
# level on the scatter the joint-estimation slips show (see RunEstimator._trial_scatter_log).
SCATTER_CONFIDENCE_QUANTILE = 0.25
# The spread of one trial's slip load assumed before 3 slips have measured it (log sd): about twice
# the trial-to-trial scatter of the simulated joints (0.085), so that a ramp slowed for the predicted
# slip load starts slowing well below it.
ONE_SLIP_SPREAD_LOG = 0.2


@dataclass(frozen=True, slots=True)
class LinkPrediction:
    """The predicted slip of the link at a configuration, from the current joint estimates."""

    slip_force_n: float
    slip_mass_kg: float
    first_slip_joint: int  # 1-based
    lever_arms_m: tuple[float, ...]  # of the line about each joint, base to tip
    base_moment_nm: float


class RunEstimator:
    """Online estimates over one run (all invocations of it)."""

    def __init__(
        self,
        article: ArticleConfig,
        *,
        level: float = 0.99,
        constant: str = "paper",
        prior_summary: FitSummary | None = None,
        estimator: EstimatorName = DEFAULT_ESTIMATOR,
    ) -> None:
        self.article = article
        self.level = level
        self.constant = constant
        self.estimator: EstimatorName = estimator
        self.fit_state = online_fit_init()  # the paper's fit, exact and O(1) per trial
        self.link_state: LinkEstimatorState | None = None
        self._file_prior = prior_summary
        # Every joint-estimation point so far (the estimators other than the paper's refit them all).
        self._distances_m: list[float] = []
        self._masses_kg: list[float] = []
        self._censored: list[bool] = []
        self._cached: tuple[int, EstimateSummary | None] = (-1, None)

    # ---- predictions -------------------------------------------------------------------------
    def paper_summary(self) -> FitSummary | None:
        """The paper's fit of the slips so far (None before 2 slips)."""
        fit = online_fit_estimate(self.fit_state, self.level)
        if fit is None:
            return None
        capacity = capacity_from_fit(fit, self.article.joint_radius_m, self.constant, self.article.g)
        return fit_summary(fit, capacity)

    def estimate_summary(self) -> EstimateSummary | None:
        """The protocol's estimator's fit with the paper's beside it (None before 2 slips)."""
        count, cached = self._cached
        if count == len(self._masses_kg):
            return cached
        result = None
        if self.fit_state.n >= 2:
            result = summarize_estimate(
                self.estimator,
                self._distances_m,
                self._masses_kg,
                self._censored,
                level=self.level,
                radius_m=self.article.joint_radius_m,
                constant=self.constant,
                g=self.article.g,
            )
        self._cached = (len(self._masses_kg), result)
        return result

    def summary(self) -> FitSummary | None:
        """The current fit by the protocol's estimator; before 2 slips the estimates file's, or None."""
        if self.estimator == "paper":
            return self.paper_summary() or self._file_prior
        full = self.estimate_summary()
        return self._file_prior if full is None else full.fit

    def predict_joint_estimation_force_n(self, distance_m: float) -> float | None:
        """Predicted slip tension at `distance_m` from the fit so far (None before 2 trials)."""
        summary = self.summary()
        if summary is None:
            return None
        return summary.capacity_nm / distance_m

    def joint_estimation_force_low_n(self, distance_m: float, z: float) -> float | None:
        """A low edge of where the next slip tension at `distance_m` lies (None: nothing to go on).

        The prediction (the fit's, or from one slip its m·l) times exp(−z·s), s the relative spread of
        one trial's slip load: the slips' trial-to-trial scatter (`_trial_scatter_log`, from 3 slips;
        `ONE_SLIP_SPREAD_LOG` before) combined with the fit's own uncertainty (its bounds' half-width
        over the level's quantile). The rate-aware ramp slows down from there (rig/runner/ramp_speed.py).
        """
        points = zip(self._distances_m, self._masses_kg, self._censored, strict=True)
        slips = [d * m for d, m, censored in points if not censored]
        summary = self.summary()
        if (not slips and summary is None) or distance_m <= 0.0:
            return None
        fit_sd = 0.0
        if summary is not None and summary.capacity_nm > 0.0 and math.isfinite(summary.capacity_nm):
            centre = summary.capacity_nm / distance_m
            lo, hi = summary.capacity_ci_nm
            quantile = NormalDist().inv_cdf(0.5 + self.level / 2.0)
            if math.isfinite(lo) and math.isfinite(hi):
                fit_sd = (hi - lo) / (2.0 * quantile * summary.capacity_nm)
        else:
            centre = float(np.mean(slips)) * self.article.g / distance_m
        spread = self._trial_scatter_log() if len(slips) >= 3 else ONE_SLIP_SPREAD_LOG
        return centre * math.exp(-z * math.hypot(spread, fit_sd))

    def transforms_for(self, joint_angles_rad: Sequence[float]) -> np.ndarray:
        """The link's (J, 4, 4) transforms at a planar configuration."""
        return planar_transforms(
            np.asarray(joint_angles_rad, float), np.asarray(self.article.segment_lengths_m)
        )

    def joint_capacities(self) -> PerJointEstimates | None:
        """Per-joint capacity estimates with bounds at the run's level, once a prior exists."""
        state = self._link()
        if state is None:
            return None
        return link_estimator_estimates(state, self.level)

    def predict_link(self, joint_angles_rad: Sequence[float]) -> LinkPrediction | None:
        """Predicted slip of the link at a measured configuration from the current estimates."""
        caps = self.joint_capacities()
        if caps is None:
            return None
        transforms = self.transforms_for(joint_angles_rad)
        pred = predict_slip(
            transforms,
            caps.capacity_nm,
            np.asarray(self.article.point_m),
            np.asarray(self.article.direction),
            g=self.article.g,
        )
        return LinkPrediction(
            slip_force_n=float(pred.slip_force_n),
            slip_mass_kg=float(pred.slip_mass_kg),
            first_slip_joint=int(pred.first_slip_joint),
            lever_arms_m=tuple(float(v) for v in np.asarray(pred.lever_arms_m)[1:]),
            base_moment_nm=float(pred.base_moment_nm),
        )

    # ---- updates -----------------------------------------------------------------------------
    def update_joint_estimation(self, distance_m: float, mass_kg: float, *, censored: bool = False) -> None:
        """Add one joint-estimation point: a slip mass, or (censored) a mass that did not slip."""
        if not censored:
            self.fit_state = online_fit_update(self.fit_state, distance_m, mass_kg)
        self._distances_m.append(float(distance_m))
        self._masses_kg.append(float(mass_kg))
        self._censored.append(censored)

    def update_link(
        self, lever_arms_m: Sequence[float], peak_force_n: float, slipped_joint: int | None
    ) -> None:
        """Add one link-validation slip at the measured configuration's lever arms."""
        state = self._link()
        if state is None:
            raise RuntimeError(
                "link validation needs joint estimates first (a joint-estimation block or a file)"
            )
        self.link_state = link_estimator_update(
            state, np.asarray(lever_arms_m, float), peak_force_n, slipped_joint
        )

    def replay(self, results: Sequence[TrialResult], source: str = "run journal") -> None:
        """Rebuild the state from journalled results, in order (used by --resume).

        A record that does not fit this rig (a damaged or edited journal) is an `InputError` naming
        `source` (the journal's path).
        """
        joints = self.article.joint_count
        for r in results:
            problem = None
            if r.slipped and r.kind == TrialKind.LINK_VALIDATION:
                if r.lever_arms_m is None or len(r.lever_arms_m) != joints:
                    problem = (
                        f"lever_arms_m has {len(r.lever_arms_m or ())} values; the rig has {joints} joints"
                    )
                elif r.slipped_joint is not None and not 1 <= r.slipped_joint <= joints:
                    problem = f"slipped_joint {r.slipped_joint}; the rig has joints 1..{joints}"
            if problem is None:
                try:
                    self.apply_result(r)
                except (ValueError, RuntimeError, AssertionError) as exc:
                    problem = str(exc)
            if problem is not None:
                raise InputError(f"{source}: trial {r.trial_id}: cannot be replayed on this rig: {problem}")

    def apply_result(self, result: TrialResult) -> None:
        """Feed one finished trial's result into the estimators.

        Slips feed the fits; a joint-estimation no-slip enters as a lower bound (the highest load
        held without a slip).
        """
        if (
            result.kind == TrialKind.JOINT_ESTIMATION
            and result.outcome == TrialOutcome.NO_SLIP
            and result.distance_m is not None
            and result.slip_mass_kg is not None
        ):
            self.update_joint_estimation(result.distance_m, result.slip_mass_kg, censored=True)
            return
        if not result.slipped:
            return
        match result.kind:
            case TrialKind.JOINT_ESTIMATION:
                assert result.distance_m is not None and result.slip_mass_kg is not None
                self.update_joint_estimation(result.distance_m, result.slip_mass_kg)
            case TrialKind.LINK_VALIDATION:
                assert result.lever_arms_m is not None and result.peak_force_n is not None
                self.update_link(result.lever_arms_m, result.peak_force_n, result.slipped_joint)
            case kind:
                assert_never(kind)

    def _link(self) -> LinkEstimatorState | None:
        if self.link_state is None:
            prior = self.summary()
            if prior is None:
                return None
            lo, hi = prior.capacity_ci_nm
            capacity = prior.capacity_nm
            # The fit's bounds on the capacity read as a log-normal spread, widened by the spread
            # between joints of one link: the fit measured one joint and the link has several.
            z = NormalDist().inv_cdf(0.5 + prior.level / 2)
            fit_sd = (math.log(hi) - math.log(lo)) / (2 * z) if 0 < lo < hi else 0.5
            sd_log = math.hypot(fit_sd, BETWEEN_JOINT_SD_LOG)
            joints = self.article.joint_count
            self.link_state = link_estimator_init(
                np.full(joints, capacity), np.full(joints, sd_log), obs_sd_log=self._trial_scatter_log()
            )
        return self.link_state

    def _trial_scatter_log(self) -> float:
        """σ of the per-joint filter: a joint's capacity scatter from trial to trial (log sd).

        The joint-estimation slips measure it: each is one draw of k times a capacity factor, so the
        relative sd of m·l estimates it. From n slips that estimate is itself uncertain (about
        1/√(2(n − 1)) relative), and a σ too small makes every joint's bounds too narrow, so the
        filter takes its upper 75 % confidence bound, √((n − 1)/χ²_{0.25, n−1}) times the estimate.
        Without data (an estimates file) or below 3 slips: the filter's default, which is also the
        floor (σ carries lever-arm and load-cell error too). studies/joint_capacity_coverage.py
        measured what the fixed default alone gave against the simulator's 0.085 scatter.
        """
        slips = [
            d * m for d, m, c in zip(self._distances_m, self._masses_kg, self._censored, strict=True) if not c
        ]
        if len(slips) < 3:
            return DEFAULT_OBS_SD_LOG
        products = np.asarray(slips)
        mean = float(products.mean())
        relative = float(products.std(ddof=1)) / abs(mean) if mean != 0 else math.inf
        if not math.isfinite(relative):
            return DEFAULT_OBS_SD_LOG
        dof = len(slips) - 1
        upper = relative * math.sqrt(dof / chi2_quantile(SCATTER_CONFIDENCE_QUANTILE, dof))
        return max(DEFAULT_OBS_SD_LOG, upper)

    def joint_estimates(self) -> tuple[JointCapacity, ...]:
        """Per-joint capacities with bounds, once link estimation has begun (else empty)."""
        caps = self.joint_capacities() if self.link_state is not None else None
        if caps is None:
            return ()
        return tuple(
            JointCapacity(
                joint=j + 1,
                capacity_nm=float(caps.capacity_nm[j]),
                ci_lo_nm=float(caps.ci_lo_nm[j]),
                ci_hi_nm=float(caps.ci_hi_nm[j]),
            )
            for j in range(len(caps.capacity_nm))
        )

    def estimate(self, trial_id: int) -> Estimate:
        """The estimate after trial `trial_id`: the fit so far (and the paper's), the per-joint capacities."""
        joints = self.joint_estimates()
        full = self.estimate_summary()
        if full is None:
            return Estimate(trial_id=trial_id, fit=self.summary(), joints=joints, estimator=self.estimator)
        est, paper, diagnostic = full.estimate, full.paper, full.estimate.diagnostic
        return Estimate(
            trial_id=trial_id,
            fit=full.fit,
            joints=joints,
            estimator=est.estimator,
            scatter_model=est.scatter_model,
            n_censored=est.n_censored,
            scatter_a_kg=est.scatter_a_kg,
            scatter_b=est.scatter_b,
            p_additive=None if diagnostic is None else diagnostic.p_additive,
            p_multiplicative=None if diagnostic is None else diagnostic.p_multiplicative,
            paper_n=None if paper is None else paper.n,
            paper_k=None if paper is None else paper.k,
            paper_k_ci=None if paper is None else paper.k_ci,
            paper_se=None if paper is None else paper.se,
            paper_rmse=None if paper is None else paper.rmse,
            paper_capacity_nm=None if paper is None else paper.capacity_nm,
            paper_capacity_ci_nm=None if paper is None else paper.capacity_ci_nm,
        )


# What an estimates file may hold (docs/formats.md §5): wide for any joint, narrow enough that the
# prior built from it (logs, ratios, predictions) stays finite.
ESTIMATE_CAPACITY_RANGE_NM = (1e-6, 1e4)
ESTIMATE_BOUND_LIMIT_NM = 1e6  # |each bound of capacity_ci_nm|
ESTIMATE_K_RANGE = (1e-8, 1e5)  # kg·m
ESTIMATE_LEVEL_RANGE = (0.001, 0.999999)
ESTIMATE_MAX_N = 1_000_000
# What a run uses (n, k, level, the capacity and its bounds) and what its log needs as numbers (the
# three pairs: /rig/estimate allows a null pair but not null bounds, and the file cannot say which).
ESTIMATE_REQUIRED = ("n", "k", "k_ci", "level", "mu_delta0_ci_pa", "capacity_nm", "capacity_ci_nm")


def load_estimates_file(path: str | Path) -> FitSummary:
    """Read an estimates JSON (a `rig fit --json` object, or a run's `.estimates.json`).

    The `ESTIMATE_REQUIRED` keys must be there; the other `rig fit` keys may be null or missing.
    Every problem is an `InputError` naming the file and the field (docs/formats.md §5).
    """
    p = Path(path)
    # A run writes its estimates with NaN for undefined statistics (R² of equal masses).
    data = load_json_file(p, what="an estimates JSON file", allow_nan=True)
    allowed = "a `rig fit --json` object or a run's .estimates.json (docs/formats.md §5)"
    where = ""
    summary = data
    if isinstance(data, dict) and "estimate" in data:
        summary, where = data["estimate"], "estimate."
        if summary is None:
            raise InputError(
                f"{p}: estimate: null (that run made no joint-estimation fit); allowed: {allowed}"
            )
    if not isinstance(summary, dict):
        raise InputError(f"{p}: {where or 'top level'}: not a JSON object; allowed: {allowed}")

    def fail(key: str, problem: str, what: str) -> InputError:
        return InputError(f"{p}: {where}{key}: {problem}; allowed: {what}")

    for key in ESTIMATE_REQUIRED:
        if summary.get(key) is None:
            raise fail(key, "missing", f"{allowed}, which has {', '.join(ESTIMATE_REQUIRED)}")

    def number(key: str, bounds: tuple[float, float] | None = None) -> float:
        """A finite number in `bounds`, or (without bounds) a number or null (NaN)."""
        value = summary.get(key)
        what = "a finite number" + (f" from {bounds[0]:g} to {bounds[1]:g}" if bounds else " or null")
        if value is None and bounds is None:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise fail(key, _short(value), what)
        x = _as_float(value)
        if bounds is None:
            return x if math.isfinite(x) else math.nan
        if not (math.isfinite(x) and bounds[0] <= x <= bounds[1]):
            raise fail(key, _short(value), what)
        return x

    def pair(key: str) -> tuple[float, float]:
        value = summary.get(key)
        what = "a list [lower, upper] of 2 finite numbers, lower <= upper"
        if not isinstance(value, list) or len(value) != 2:
            raise fail(key, _short(value), what)
        for i, bound in enumerate(value):
            if (
                isinstance(bound, bool)
                or not isinstance(bound, int | float)
                or not math.isfinite(_as_float(bound))
            ):
                raise fail(f"{key}[{i}]", _short(bound), what)
        lo, hi = (_as_float(bound) for bound in value)
        if lo > hi:
            raise fail(key, _short(value), what)
        return lo, hi

    def integer(key: str, lo: int, hi: int) -> int:
        value = summary.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise fail(key, _short(value), f"an integer from {lo} to {hi}")
        return value

    n = integer("n", 2, ESTIMATE_MAX_N)
    capacity = number("capacity_nm", ESTIMATE_CAPACITY_RANGE_NM)
    lo, hi = pair("capacity_ci_nm")
    limit = ESTIMATE_BOUND_LIMIT_NM
    if not -limit <= lo <= capacity <= hi <= limit:
        raise fail(
            "capacity_ci_nm",
            f"[{lo:g}, {hi:g}] for capacity_nm {capacity:g}",
            f"lower <= capacity_nm <= upper, each within ±{limit:g} N·m",
        )
    constant = summary.get("constant")
    if constant is None:
        constant = "unknown"
    if not isinstance(constant, str) or len(constant) > 64:
        raise fail("constant", _short(constant), "a name such as paper or derived, or null")
    dfe = n - 1 if summary.get("dfe") is None else integer("dfe", 1, ESTIMATE_MAX_N)
    return FitSummary(
        n=n,
        k=number("k", ESTIMATE_K_RANGE),
        k_ci=pair("k_ci"),
        sse=number("sse"),
        sst=number("sst"),
        r2=number("r2"),
        rmse=number("rmse"),
        dfe=dfe,
        se=number("se"),
        level=number("level", ESTIMATE_LEVEL_RANGE),
        constant=constant,
        c=number("c"),
        radius_m=number("radius_m"),
        mu_delta0_pa=number("mu_delta0_pa"),
        mu_delta0_ci_pa=pair("mu_delta0_ci_pa"),
        capacity_nm=capacity,
        capacity_ci_nm=(lo, hi),
    )


def _as_float(value: int | float) -> float:
    try:
        return float(value)
    except OverflowError:  # an integer beyond the float range
        return math.inf


def _short(value: Any) -> str:
    if isinstance(value, int) and value.bit_length() > 100:
        return "an integer beyond the float range"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


@lru_cache(maxsize=256)
def chi2_quantile(probability: float, dof: int) -> float:
    """The χ² quantile (scipy, imported on first use)."""
    from scipy import stats

    return float(stats.chi2.ppf(probability, dof))
