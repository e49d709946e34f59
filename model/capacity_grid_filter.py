"""Per-joint capacity estimates from link-validation slips: a Bayesian grid filter, pure step functions.

Observation (docs/model.md §3, Corollary 2; §5). A link-validation trial loads the tip along one direction
until the link slips at peak tension f. With lever arms d_i (joint i's moment per newton of load),
the joint j that slipped carried moment f·d_j ≈ its capacity C_j, and every other joint i held,
so C_i ≳ f·d_i. When the slipping joint is not identified, only `min_i C_i/d_i ≈ f` is known.

Statistical model. Log-capacities θ_i = ln C_i.
* Prior: independent Gaussians θ_i ~ N(ln C_i⁰, s_i²), usually from the joint-estimation fit
  (`LinkCapacityPrior.from_capacity_estimate`: its bounds read as a log-normal spread, widened by
  an optional between-joint spread, because that fit measured one joint and the link has several).
* Trial-to-trial variation (friction scatter, load-cell and lever-arm error) is multiplicative:
  in a trial joint i resists up to C_i·e^{ε_i}, ε_i ~ N(0, σ²) independent (σ = `obs_sd_log`). The
  joint with the smallest C_i·e^{ε_i}/d_i slips, at f = C_j·e^{ε_j}/d_j. The exact likelihood is then
  - slipped joint j: the density of ε_j = ln(f·d_j) − θ_j, i.e. N(ln(f·d_j); θ_j, σ²);
  - each held joint i: P(ε_i > ln(f·d_i) − θ_i) = Φ((θ_i − ln(f·d_i))/σ), a censored observation
    that can only raise the joint's lower tail;
  - a joint with d_i = 0 carries no moment and learns nothing.
  With an identified slip the posterior stays a product over joints: each joint's marginal is
  updated by its own factor, exactly.
* Unidentified slip: the likelihood is the mixture Σ_j [slip density of j · Π_{i≠j} held factor of i].
  Its posterior is a mixture over "which joint slipped", with weight w_j ∝ Z_j, the evidence of that
  hypothesis (the posterior probability that joint j was the weakest relative to its lever arm).
  Each joint's new marginal is `w_i · (slipped-update of i) + (1 − w_i) · (held-update of i)`, and the
  state keeps only these marginals (assumed-density filtering: the exact posterior's marginals
  after this update, with the correlation the mixture induces dropped, so later updates are
  approximate). The weights are exposed as `last_slip_probabilities`.

Representation. Each joint's marginal lives on its own uniform grid in θ (G points spanning at
least ±10 prior sd and ±ln 2 about the prior median, spaced at most min(s_i, σ)/8), as normalised
log-weights, so every update is a few vectorised (J, G) array operations with no sampling
and no randomness. Estimates are the posterior median and equal-tailed credible bounds of C_i.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special, stats

from model.fit import CapacityEstimate

DEFAULT_OBS_SD_LOG: Final[float] = 0.05
MAX_GRID_POINTS: Final[int] = 20001
_MIN_HALF_WIDTH_LOG: Final[float] = math.log(2.0)
_HALF_WIDTH_PRIOR_SDS: Final[float] = 10.0
_POINTS_PER_SD: Final[float] = 8.0
_LOG_SQRT_2PI: Final[float] = 0.5 * math.log(2.0 * math.pi)


def _readonly(array: NDArray[np.float64]) -> NDArray[np.float64]:
    array.setflags(write=False)
    return array


def _positive_vector(name: str, values: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
    array = np.atleast_1d(np.asarray(values, dtype=float)).copy()
    if array.ndim != 1 or array.size == 0:
        raise ValueError(f"{name}: shape {array.shape}; allowed: one value per joint")
    if n is not None and array.size == 1 and n > 1:
        array = np.full(n, array[0])
    if n is not None and array.size != n:
        raise ValueError(f"{name}: {array.size} values for {n} joints; allowed: one per joint")
    bad = np.flatnonzero(~(np.isfinite(array) & (array > 0)))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] = {float(array[bad[0]])!r}; allowed: finite and > 0")
    return array


@dataclass(frozen=True)
class LinkCapacityPrior:
    """Independent log-normal priors on the joints' capacities: median `capacity_nm`, log-sd `sd_log`."""

    capacity_nm: NDArray[np.float64]
    sd_log: NDArray[np.float64]

    def __post_init__(self) -> None:
        """Validate (positive, finite, one value each) and freeze the arrays."""
        capacity = _positive_vector("prior capacity_nm", self.capacity_nm)
        sd = _positive_vector("prior sd_log", self.sd_log, capacity.size)
        object.__setattr__(self, "capacity_nm", _readonly(capacity))
        object.__setattr__(self, "sd_log", _readonly(sd))

    @classmethod
    def from_capacity_estimate(
        cls, estimate: CapacityEstimate, n_joints: int, between_joint_sd_log: float = 0.0
    ) -> LinkCapacityPrior:
        """Every joint like the fitted one: median = its capacity, log-sd from its bounds.

        The bounds C ± t·se at the estimate's level are read as a Gaussian of the same width in
        log-capacity: sd = (hi − lo) / (2·z·C), z the normal quantile at (1 + level)/2 (this widens
        the prior for small n, where t > z). `between_joint_sd_log` adds joint-to-joint spread in
        quadrature (the fit measured one joint).
        """
        if not (isinstance(n_joints, int) and n_joints >= 1):
            raise ValueError(f"n_joints = {n_joints!r}; allowed: an integer >= 1")
        if not (math.isfinite(between_joint_sd_log) and between_joint_sd_log >= 0):
            raise ValueError(f"between_joint_sd_log = {between_joint_sd_log!r}; allowed: finite and >= 0")
        capacity = estimate.capacity_nm
        if not (math.isfinite(capacity) and capacity > 0):
            raise ValueError(f"capacity_nm = {capacity!r}; allowed: a fit with a positive capacity")
        lo, hi = estimate.capacity_ci_nm
        z = float(stats.norm.ppf(0.5 * (1.0 + estimate.level)))
        fit_sd_log = (hi - lo) / (2.0 * z * capacity)
        sd_log = math.hypot(fit_sd_log, between_joint_sd_log)
        if not sd_log > 0:
            raise ValueError(
                "the fit has zero-width bounds, so the prior would have sd 0; allowed: "
                "set between_joint_sd_log > 0"
            )
        return cls(np.full(n_joints, capacity), np.full(n_joints, sd_log))


@dataclass(frozen=True)
class LinkEstimatorState:
    """Per-joint posterior marginals of log-capacity on grids (immutable).

    Attributes:
        prior: the prior it started from.
        obs_sd_log: σ, the trial-to-trial log-scatter of a joint's capacity.
        log_grid: (J, G) log-capacity grid points, ln N·m, one uniform grid per joint.
        log_weights: (J, G) normalised log posterior weights on those points.
        n_updates: number of slips absorbed.
        last_slip_probabilities: (J,) probability each joint was the one that slipped in the last
            update (one-hot when identified), or None before any update.
    """

    prior: LinkCapacityPrior
    obs_sd_log: float
    log_grid: NDArray[np.float64]
    log_weights: NDArray[np.float64]
    n_updates: int = 0
    last_slip_probabilities: NDArray[np.float64] | None = None

    @property
    def n_joints(self) -> int:
        """Number of joints J."""
        return int(self.log_grid.shape[0])


@dataclass(frozen=True)
class PerJointEstimates:
    """Posterior summaries per joint (J,): median capacity and equal-tailed bounds at `level`.

    Attributes:
        capacity_nm: posterior median capacity [N·m].
        ci_lo_nm, ci_hi_nm: the (1 − level)/2 and (1 + level)/2 posterior quantiles [N·m].
        sd_log: posterior standard deviation of ln capacity.
        sd_nm: posterior standard deviation of the capacity [N·m].
        level: the credible level of the bounds.
    """

    capacity_nm: NDArray[np.float64]
    ci_lo_nm: NDArray[np.float64]
    ci_hi_nm: NDArray[np.float64]
    sd_log: NDArray[np.float64]
    sd_nm: NDArray[np.float64]
    level: float


def link_estimator_init(
    prior: ArrayLike | LinkCapacityPrior | CapacityEstimate,
    prior_sd_log: ArrayLike | None = None,
    *,
    obs_sd_log: float = DEFAULT_OBS_SD_LOG,
    n_joints: int | None = None,
    between_joint_sd_log: float = 0.0,
) -> LinkEstimatorState:
    """The estimator before any link-validation slip.

    `prior` is either the prior median capacities [N·m] (J,) with `prior_sd_log` (J,) or a scalar,
    a `LinkCapacityPrior`, or a `CapacityEstimate` from the joint-estimation fit (then give
    `n_joints`; see `LinkCapacityPrior.from_capacity_estimate`). `obs_sd_log` is σ (module docstring).
    """
    if isinstance(prior, LinkCapacityPrior):
        resolved = prior
    elif isinstance(prior, CapacityEstimate):
        if n_joints is None:
            raise ValueError("a CapacityEstimate prior needs n_joints; allowed: an integer >= 1")
        resolved = LinkCapacityPrior.from_capacity_estimate(prior, n_joints, between_joint_sd_log)
    else:
        if prior_sd_log is None:
            raise ValueError("prior_sd_log is required with prior capacities; allowed: > 0 per joint")
        capacity = _positive_vector("prior capacity_nm", prior)
        resolved = LinkCapacityPrior(capacity, _positive_vector("prior sd_log", prior_sd_log, capacity.size))
    sigma = float(obs_sd_log)
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"obs_sd_log = {obs_sd_log!r}; allowed: finite and > 0")

    centre = np.log(resolved.capacity_nm)
    sd = resolved.sd_log
    half_width = np.maximum(_HALF_WIDTH_PRIOR_SDS * sd, _MIN_HALF_WIDTH_LOG)
    step = np.minimum(sd, sigma) / _POINTS_PER_SD
    points = int(min(MAX_GRID_POINTS, max(201, math.ceil(float(np.max(2 * half_width / step))) + 1)))
    unit = np.linspace(-1.0, 1.0, points)
    log_grid = centre[:, None] + half_width[:, None] * unit[None, :]
    z = (log_grid - centre[:, None]) / sd[:, None]
    log_weights = _normalised(-0.5 * z * z)
    return LinkEstimatorState(resolved, sigma, _readonly(log_grid), _readonly(log_weights))


def _normalised(log_weights: NDArray[np.float64]) -> NDArray[np.float64]:
    normalised: NDArray[np.float64] = log_weights - special.logsumexp(log_weights, axis=1, keepdims=True)
    return normalised


def link_estimator_update(
    state: LinkEstimatorState,
    lever_arms_m: ArrayLike,
    peak_force_n: float,
    slipped_joint: int | None,
) -> LinkEstimatorState:
    """Absorb one slip at `peak_force_n` [N] with lever arms `lever_arms_m` (J,) [m].

    `slipped_joint` is the 1-based joint that slipped (joint 1 nearest the base), or None when it
    was not identified. Raises ValueError for a lever arm that is negative or not finite, all lever
    arms zero, a force that is not finite and > 0, or a joint outside 1..J (or with lever arm 0).
    """
    n = state.n_joints
    arms = np.asarray(lever_arms_m, dtype=float)
    if arms.shape != (n,):
        raise ValueError(f"lever_arms_m: shape {arms.shape}; allowed: ({n},), one per joint")
    bad = np.flatnonzero(~(np.isfinite(arms) & (arms >= 0)))
    if bad.size:
        raise ValueError(f"lever_arms_m[{bad[0]}] = {float(arms[bad[0]])!r}; allowed: finite and >= 0 m")
    loaded = arms > 0
    if not loaded.any():
        raise ValueError("every lever arm is 0: no joint carries a moment; allowed: at least one > 0")
    force = float(peak_force_n)
    if not (math.isfinite(force) and force > 0):
        raise ValueError(f"peak_force_n = {peak_force_n!r}; allowed: finite and > 0 N")
    if slipped_joint is not None:
        if isinstance(slipped_joint, bool) or not isinstance(slipped_joint, int | np.integer):
            raise ValueError(f"slipped_joint = {slipped_joint!r}; allowed: an integer 1..{n} or None")
        if not 1 <= slipped_joint <= n:
            raise ValueError(f"slipped_joint = {slipped_joint}; allowed: 1..{n} or None")
        if not loaded[slipped_joint - 1]:
            raise ValueError(
                f"slipped_joint = {slipped_joint} has lever arm 0 and cannot slip; "
                "allowed: a joint with lever arm > 0"
            )

    sigma = state.obs_sd_log
    log_moment = np.full(n, -np.inf)
    log_moment[loaded] = math.log(force) + np.log(arms[loaded])
    z = (state.log_grid - log_moment[:, None]) / sigma  # +inf rows for unloaded joints
    log_held = special.log_ndtr(z)  # 0 where unloaded: P(held) = 1
    with np.errstate(invalid="ignore"):
        log_slip = -0.5 * z * z - math.log(sigma) - _LOG_SQRT_2PI  # -inf where unloaded
    prior = state.log_weights
    after_slip = prior + log_slip
    after_held = prior + log_held

    if slipped_joint is not None:
        probabilities = np.zeros(n)
        probabilities[slipped_joint - 1] = 1.0
        log_weights = after_held.copy()
        log_weights[slipped_joint - 1] = after_slip[slipped_joint - 1]
    else:
        evidence_slip = special.logsumexp(after_slip, axis=1)  # ln ∫ p_i · slip density
        evidence_held = special.logsumexp(after_held, axis=1)  # ln ∫ p_i · P(held)
        logits = np.where(loaded, evidence_slip - evidence_held, -np.inf)
        probabilities = np.exp(logits - special.logsumexp(logits))
        # Mixture of the two updates per joint; a component of weight 0 is left out (its evidence
        # may be -inf, e.g. an unloaded joint cannot have slipped).
        slip_part = np.full_like(prior, -np.inf)
        held_part = np.full_like(prior, -np.inf)
        can_slip = probabilities > 0
        can_hold = probabilities < 1
        slip_part[can_slip] = (
            np.log(probabilities[can_slip])[:, None] + after_slip[can_slip] - evidence_slip[can_slip, None]
        )
        held_part[can_hold] = (
            np.log1p(-probabilities[can_hold])[:, None] + after_held[can_hold] - evidence_held[can_hold, None]
        )
        log_weights = np.logaddexp(slip_part, held_part)
    log_weights = _normalised(log_weights)
    if not np.all(np.isfinite(special.logsumexp(log_weights, axis=1))):
        raise ValueError("this slip is impossible under the current estimates (posterior underflow)")
    return LinkEstimatorState(
        prior=state.prior,
        obs_sd_log=sigma,
        log_grid=state.log_grid,
        log_weights=_readonly(log_weights),
        n_updates=state.n_updates + 1,
        last_slip_probabilities=_readonly(probabilities),
    )


def link_estimator_estimates(state: LinkEstimatorState, level: float = 0.99) -> PerJointEstimates:
    """Posterior median capacity, equal-tailed bounds at `level`, and spread, per joint."""
    level_value = float(level)
    if not (0.0 < level_value < 1.0):
        raise ValueError(f"level {level!r}: allowed: a number in the open interval (0, 1)")
    weights = np.exp(state.log_weights)
    weights /= weights.sum(axis=1, keepdims=True)
    grid = state.log_grid
    # Mid-point CDF: each grid point holds its weight centred on it.
    cdf = np.cumsum(weights, axis=1) - 0.5 * weights
    quantiles = np.array([(1.0 - level_value) / 2.0, 0.5, (1.0 + level_value) / 2.0])
    log_q = np.array([np.interp(quantiles, cdf[i], grid[i]) for i in range(state.n_joints)])
    mean_log = (weights * grid).sum(axis=1)
    sd_log = np.sqrt((weights * (grid - mean_log[:, None]) ** 2).sum(axis=1))
    capacity = np.exp(grid)
    mean_nm = (weights * capacity).sum(axis=1)
    sd_nm = np.sqrt((weights * (capacity - mean_nm[:, None]) ** 2).sum(axis=1))
    return PerJointEstimates(
        capacity_nm=_readonly(np.exp(log_q[:, 1])),
        ci_lo_nm=_readonly(np.exp(log_q[:, 0])),
        ci_hi_nm=_readonly(np.exp(log_q[:, 2])),
        sd_log=_readonly(sd_log),
        sd_nm=_readonly(sd_nm),
        level=level_value,
    )
