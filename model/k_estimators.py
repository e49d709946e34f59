"""Estimators of k in `m = k / l` beyond the paper's fit, behind one interface (see `estimate_k`).

* `paper`: the paper's least squares through the origin with MATLAB cftool bounds (`model.fit`),
  exact and unchanged. It assumes the same scatter at every distance. Censored points (no slip
  before the force limit) are excluded: cftool has no notion of a lower bound.
* `weighted`: the mean of m·l with a Student-t interval; the efficient estimate when the scatter of a
  slip mass is proportional to it (each trial is then one draw of k times a capacity factor). With
  censored points it becomes the censored (Tobit) likelihood under that scatter model.
* `auto`: averages the weighted least squares k over scatter shapes σ² ∝ (1 − θ) + θ·(x/x_ref)²
  (θ = 0 additive, θ = 1 multiplicative, a grid of mixed shapes between), each weighted by its
  restricted likelihood (scale profiled out) and a prior that favours the additive model; bounds
  from the larger of the model-based and the delete-one jackknife standard error, and a
  likelihood-ratio diagnostic of which scatter model the data support. Censored points enter
  through the Tobit likelihood with the fitted shape. docs/model.md §4.2 has the derivations.

Every estimator takes the same data (distances, masses, and which masses are only lower bounds)
and returns a `KEstimate`. `auto_batch` is the uncensored `auto` vectorised over many data sets of
one design (the coverage studies use it; `estimate_k` calls it with one data set, so both are the
same arithmetic). `crlb_k` is the Cramér-Rao bound on the variance of k for a design and a scatter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np

from model.fit import DEFAULT_LEVEL, check_level, check_pair, fit_inverse_distance, t_quantile

EstimatorName = Literal["paper", "weighted", "auto"]
ESTIMATOR_NAMES: Final[tuple[EstimatorName, ...]] = ("paper", "weighted", "auto")
DEFAULT_ESTIMATOR: Final[EstimatorName] = "auto"
ScatterModel = Literal["additive", "multiplicative", "mixed"]
SCATTER_MODELS: Final[tuple[ScatterModel, ...]] = ("additive", "multiplicative", "mixed")

# A no-slip bound the slips' own fit makes this improbable (P(m > bound) below it) is not a lower bound
# from the same scatter but a joint that held (a jam, a fixture): it is left out, with the reason.
CENSORED_CONSISTENCY_P: Final[float] = 1e-3
# The diagnostic rejects a restricted scatter model below this p-value.
DIAGNOSTIC_ALPHA: Final[float] = 0.05
# `auto` averages over scatter shapes (see `_shape_grid`): additive, multiplicative, and
# SHAPE_GRID_POINTS mixed shapes evenly in logit(θ) over ±SHAPE_LOGIT_RANGE (θ from 0.047 to 0.953).
SHAPE_GRID_POINTS: Final[int] = 33
SHAPE_LOGIT_RANGE: Final[float] = 3.0
# Prior weights of the three models (the mixed one spread evenly over its grid). They and the power
# on the likelihood were chosen with studies/estimator_coverage.py (seeds 1-4, not the reported
# seed 0) to keep the MSE within 1.1x the Cramér-Rao bound for every shape: an additive scatter
# needs most protection (a b fitted where there is none moves weight off the short distances, which
# carry nearly all the information on a wide design), a multiplicative one the least.
PRIOR_ADDITIVE: Final[float] = 1.0
PRIOR_MIXED: Final[float] = 1.0
PRIOR_MULTIPLICATIVE: Final[float] = 0.2
LIKELIHOOD_POWER: Final[float] = 1.5
# The bounds use the larger of two standard errors, each scaled (chosen with the same study): the
# delete-one jackknife runs low and is noisy where a few short-distance points carry most of the
# information (alone it covers 0.985 under additive and mixed scatter on 0.03-0.25 m), so it is
# scaled up; the model-based se alone already covers about 0.99 when the shape is right, and the
# larger of two noisy estimates runs high, so it is scaled down.
JACKKNIFE_SE_FACTOR: Final[float] = 1.07
MODEL_SE_FACTOR: Final[float] = 0.9
# A scatter variance below this fraction of the masses' mean square is taken as zero (exact data).
_RELATIVE_FLOOR: Final[float] = 1e-12
# Data sets per block of the jackknife (its arrays are data sets x points x shapes).
_JACKKNIFE_BLOCK: Final[int] = 2000


@dataclass(frozen=True, slots=True)
class ScatterDiagnostic:
    """Which scatter model the data support: likelihood-ratio tests of each restricted model.

    `lr_additive` = 2(ℓ_mixed − ℓ_additive) tests b = 0; `lr_multiplicative` tests a = 0. The
    parameter sits on the boundary under the null, so the p-value is the ½χ²₀ + ½χ²₁ mixture's.
    `supported` is the model the tests leave (both rejected: mixed; neither: the likelier one);
    `decided` is False when neither restricted model was rejected (too few data to tell).
    """

    lr_additive: float
    p_additive: float
    lr_multiplicative: float
    p_multiplicative: float
    supported: ScatterModel
    decided: bool


@dataclass(frozen=True, slots=True)
class KEstimate:
    """One estimator's k [kg·m] with its bounds at `level`, and what it assumed of the scatter."""

    estimator: EstimatorName
    scatter_model: str  # "additive", "multiplicative" or "mixed"
    n: int  # data points used
    n_censored: int  # of those, lower bounds only (no slip before the force limit)
    k: float
    k_ci: tuple[float, float]
    se: float
    level: float
    # The scatter of one slip mass m under the fitted model: sd(m)^2 = a^2 + (b*m)^2 (a [kg], b relative).
    scatter_a_kg: float
    scatter_b: float
    diagnostic: ScatterDiagnostic | None = None  # auto only
    n_excluded: int = 0  # points left out (the paper's fit leaves out censored points)
    note: str = ""  # why points were left out, if any


def check_estimator(name: str) -> EstimatorName:
    """`name` as an estimator name; ValueError listing the allowed ones otherwise."""
    for allowed in ESTIMATOR_NAMES:
        if name == allowed:
            return allowed
    raise ValueError(f"estimator {name!r}; allowed: {', '.join(ESTIMATOR_NAMES)}")


def crlb_k(
    distances_m: Sequence[float] | np.ndarray, k: float, scatter_a_kg: float, scatter_b: float
) -> float:
    """Cramér-Rao bound on the variance of an unbiased k̂ [(kg·m)²] for a design and a scatter.

    Masses m_i ~ N(k x_i, σ_i²), x_i = 1/l_i, σ_i² = a² + (b k x_i)², with a and b unknown. The
    Fisher information is I_kk = Σ x²/σ² + ½ Σ (∂σ²/∂k)²/σ⁴, but ∂σ²/∂k = (2/k)·b²·∂σ²/∂(b²):
    the variance carries information on k only through a direction b² already spans, so after
    profiling the nuisance (a², b²) the bound is 1/Σ(x_i²/σ_i²), the weighted least squares variance.
    tests/test_study.py checks it against the inverse of the full information matrix with the
    nuisance parameters. Pure multiplicative gives b²k²/n (the variance of the mean of m·l), pure
    additive a²/Σx² (the paper's fit). NaN when the design carries no information (no distances,
    or no scatter at all).
    """
    x = 1.0 / np.asarray(distances_m, dtype=float)
    if x.size == 0 or not (scatter_a_kg > 0 or scatter_b > 0):
        return math.nan
    variance = scatter_a_kg**2 + (scatter_b * k * x) ** 2
    return float(1.0 / np.sum(x * x / variance))


def _checked_data(
    distances_m: Sequence[float], masses_kg: Sequence[float], censored: Sequence[bool] | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if len(distances_m) != len(masses_kg):
        raise ValueError(f"{len(distances_m)} distances but {len(masses_kg)} masses; allowed: one each")
    flags = [False] * len(masses_kg) if censored is None else [bool(c) for c in censored]
    if len(flags) != len(masses_kg):
        raise ValueError(f"{len(flags)} censoring flags for {len(masses_kg)} masses; allowed: one each")
    pairs = [
        check_pair(d, m, where=f"point {i}")
        for i, (d, m) in enumerate(zip(distances_m, masses_kg, strict=True), 1)
    ]
    distances = np.array([d for d, _ in pairs], dtype=float)
    masses = np.array([m for _, m in pairs], dtype=float)
    return distances, masses, np.array(flags, dtype=bool)


def _need_slips(n: int) -> None:
    if n < 2:
        raise ValueError(f"{n} slip(s); allowed: at least 2 for a fit")


def paper_estimate(
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """The paper's fit over the slips only (censored points are excluded: cftool has no such notion)."""
    distances, masses, flags = _checked_data(distances_m, masses_kg, censored)
    fit = fit_inverse_distance(distances[~flags], masses[~flags], level)
    excluded = int(flags.sum())
    note = (
        f"{excluded} censored point(s) excluded: cftool's least squares has no notion of a lower bound"
        if excluded
        else ""
    )
    return KEstimate(
        "paper", "additive", fit.n, 0, fit.k, fit.k_ci, fit.se, fit.level, fit.rmse, 0.0, None, excluded, note
    )


def weighted_estimate(
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """Mean of m·l with a Student-t interval on n − 1 degrees of freedom.

    With censored points: the Tobit likelihood under the same (multiplicative) scatter model.
    """
    level = check_level(level)
    distances, masses, flags = _checked_data(distances_m, masses_kg, censored)
    _need_slips(int((~flags).sum()))
    note = ""
    excluded = 0
    if flags.any():
        products = distances[~flags] * masses[~flags]
        k0 = float(products.mean())
        sd0 = float(products.std(ddof=1)) / k0 if k0 != 0.0 else math.inf
        keep, note = _screen_censored(1.0 / distances, masses, flags, k0, 0.0, sd0)
        excluded = int((~keep).sum())
        distances, masses, flags = distances[keep], masses[keep], flags[keep]
    if flags.any():
        x = 1.0 / distances
        k0 = float(np.mean(masses[~flags] * distances[~flags]))
        k, se, sd_rel = _tobit(x, masses, flags, alpha=0.0, beta=1.0, k_start=k0)
        half = t_quantile(level, masses.size - 1) * se
        return KEstimate(
            "weighted",
            "multiplicative",
            int(masses.size),
            int(flags.sum()),
            k,
            (k - half, k + half),
            se,
            level,
            0.0,
            sd_rel,
            None,
            excluded,
            note,
        )
    products = distances * masses
    n = int(products.size)
    k = float(products.mean())
    se = float(products.std(ddof=1)) / math.sqrt(n)
    half = t_quantile(level, n - 1) * se
    relative_sd = float(products.std(ddof=1)) / k if k != 0.0 else math.inf
    return KEstimate(
        "weighted",
        "multiplicative",
        n,
        0,
        k,
        (k - half, k + half),
        se,
        level,
        0.0,
        relative_sd,
        None,
        excluded,
        note,
    )


@dataclass(frozen=True, slots=True)
class AutoBatch:
    """`auto` over B data sets of one design (arrays of shape (B,)); t is the bound's quantile."""

    k: np.ndarray
    se: np.ndarray
    t: float
    scatter_a_kg: np.ndarray
    scatter_b: np.ndarray
    lr_additive: np.ndarray
    lr_multiplicative: np.ndarray


def _half_chi2_1_sf(statistic: np.ndarray) -> np.ndarray:
    """P(½χ²₀ + ½χ²₁ > s) = ½ erfc(√(s/2)) for s > 0 (and 1 at s = 0)."""
    s = np.maximum(statistic, 0.0)
    tail = 0.5 * np.vectorize(math.erfc, otypes=[float])(np.sqrt(s / 2.0))
    return np.where(s > 0.0, tail, 1.0)


@dataclass(frozen=True, slots=True)
class _ShapeGrid:
    """The scatter shapes `auto` averages over, for one design.

    Shape g gives point i the relative variance v_gi = (1 − θ_g) + θ_g·(x_i/x_ref)², x_ref the rms of
    x: θ = 0 is additive, θ = 1 multiplicative, and θ is the multiplicative share of the variance at
    x_ref. Since μ_i = k·x_i, this is σ_i² = a² + (b·μ_i)² with a² = s²(1 − θ), b² = s²θ/(k·x_ref)².
    """

    theta: np.ndarray  # (G,)
    log_prior: np.ndarray  # (G,)
    weight: np.ndarray  # (G, n): 1/v
    x_ref: float


def _shape_grid(x: np.ndarray) -> _ShapeGrid:
    inner = 1.0 / (1.0 + np.exp(-np.linspace(-SHAPE_LOGIT_RANGE, SHAPE_LOGIT_RANGE, SHAPE_GRID_POINTS)))
    theta = np.concatenate([[0.0], inner, [1.0]])
    mixed = np.full(SHAPE_GRID_POINTS, PRIOR_MIXED / SHAPE_GRID_POINTS)
    prior = np.concatenate([[PRIOR_ADDITIVE], mixed, [PRIOR_MULTIPLICATIVE]])
    x_ref = float(np.sqrt(np.mean(x * x)))
    relative = (x / x_ref) ** 2
    variance = (1.0 - theta)[:, None] + theta[:, None] * relative[None, :]
    return _ShapeGrid(theta=theta, log_prior=np.log(prior), weight=1.0 / variance, x_ref=x_ref)


@dataclass(frozen=True, slots=True)
class _Average:
    """`auto`'s k averaged over the shapes, per data set (arrays of the data sets' shape)."""

    k: np.ndarray
    se_model: np.ndarray  # 1/√(Σ_g p_g·Σw x²/s_g²): the shapes' information, averaged
    alpha: np.ndarray  # a² [kg²], posterior mean
    beta: np.ndarray  # b², posterior mean
    lr_additive: np.ndarray  # 2(max_g ℓ_g − ℓ_additive), ℓ the Gaussian log-likelihood at each fit
    lr_multiplicative: np.ndarray


def _average(
    grid: _ShapeGrid, sxx: np.ndarray, sxm: np.ndarray, smm: np.ndarray, log_det: np.ndarray, n: int
) -> _Average:
    """Average over the shapes from the weighted sums of each (last axis: the shapes).

    sxx = Σ w x², sxm = Σ w x m, smm = Σ w m², log_det = Σ log v (over the points of a data set).
    """
    k_g = sxm / sxx
    # Weighted residual sum of squares; a floor keeps exact data (q = 0 up to rounding) finite.
    q = np.maximum(smm - sxm * k_g, _RELATIVE_FLOOR * smm + 1e-300)
    # Restricted (REML) log-likelihood of the shape with the scale s² profiled out.
    restricted = -0.5 * (log_det + np.log(sxx) + (n - 1) * np.log(q))
    log_post = LIKELIHOOD_POWER * restricted + grid.log_prior
    log_post = log_post - log_post.max(axis=-1, keepdims=True)
    post = np.exp(log_post)
    post = post / post.sum(axis=-1, keepdims=True)
    k = (post * k_g).sum(axis=-1)
    scale2 = q / max(n - 1, 1)
    se_model = 1.0 / np.sqrt((post * sxx / scale2).sum(axis=-1))
    alpha = (post * scale2 * (1.0 - grid.theta)).sum(axis=-1)
    mult = (post * scale2 * grid.theta).sum(axis=-1)
    denominator = (k * grid.x_ref) ** 2
    beta = np.where(denominator > 0.0, mult / np.where(denominator > 0.0, denominator, 1.0), 0.0)
    # Maximum likelihood of each shape (scale s² = q/n): the diagnostic's statistics.
    full = -0.5 * (log_det + n * np.log(q / n))
    best = full.max(axis=-1)
    return _Average(
        k=k,
        se_model=se_model,
        alpha=alpha,
        beta=beta,
        lr_additive=2.0 * (best - full[..., 0]),
        lr_multiplicative=2.0 * (best - full[..., -1]),
    )


def auto_batch(distances_m: np.ndarray, masses_kg: np.ndarray, level: float = DEFAULT_LEVEL) -> AutoBatch:
    """The uncensored `auto` estimate for each row of `masses_kg` (B, n) at `distances_m` (n,).

    k is the average of the weighted least squares estimates over the scatter shapes, each weighted
    by its restricted likelihood (raised to `LIKELIHOOD_POWER`) times its prior. se is the larger of
    the model-based standard error of that average and the delete-one jackknife of the whole
    estimator (which also sees the shape's own uncertainty and a scatter model that does not hold);
    bounds k ± t_{n−1}·se. The jackknife keeps the full data set's shape grid (x_ref), so each
    left-out fit is the sums minus one point's terms.
    """
    level = check_level(level)
    x = 1.0 / np.asarray(distances_m, dtype=float)
    m = np.atleast_2d(np.asarray(masses_kg, dtype=float))
    n = x.size
    _need_slips(n)
    grid = _shape_grid(x)
    wx = grid.weight * x  # (G, n)
    terms_xx = wx * x  # (G, n)
    terms_xm = m[:, :, None] * wx.T[None, :, :]  # (B, n, G)
    terms_mm = (m * m)[:, :, None] * grid.weight.T[None, :, :]
    log_v = -np.log(grid.weight)  # (G, n)
    sxx = terms_xx.sum(axis=1)
    sxm = terms_xm.sum(axis=1)
    smm = terms_mm.sum(axis=1)
    log_det = log_v.sum(axis=1)
    whole = _average(grid, sxx, sxm, smm, log_det, n)
    se = whole.se_model.copy()
    if n >= 3:
        # Leave-one-out sums (data sets, left-out point, shape), a block of data sets at a time.
        for lo in range(0, m.shape[0], _JACKKNIFE_BLOCK):
            rows = slice(lo, lo + _JACKKNIFE_BLOCK)
            out = _average(
                grid,
                sxx[None, None, :] - terms_xx.T[None, :, :],
                sxm[rows, None, :] - terms_xm[rows],
                smm[rows, None, :] - terms_mm[rows],
                log_det[None, None, :] - log_v.T[None, :, :],
                n - 1,
            )
            spread = out.k - out.k.mean(axis=1, keepdims=True)
            jackknife = JACKKNIFE_SE_FACTOR * np.sqrt((n - 1) / n * (spread * spread).sum(axis=1))
            se[rows] = np.maximum(MODEL_SE_FACTOR * whole.se_model[rows], jackknife)
    return AutoBatch(
        k=whole.k,
        se=se,
        t=t_quantile(level, n - 1),
        scatter_a_kg=np.sqrt(whole.alpha),
        scatter_b=np.sqrt(whole.beta),
        lr_additive=whole.lr_additive,
        lr_multiplicative=whole.lr_multiplicative,
    )


def diagnose(lr_additive: float, lr_multiplicative: float) -> ScatterDiagnostic:
    """The verdict of the two likelihood-ratio statistics at `DIAGNOSTIC_ALPHA`."""
    p_add = float(_half_chi2_1_sf(np.array([lr_additive]))[0])
    p_mul = float(_half_chi2_1_sf(np.array([lr_multiplicative]))[0])
    reject_add, reject_mul = p_add < DIAGNOSTIC_ALPHA, p_mul < DIAGNOSTIC_ALPHA
    supported: ScatterModel
    if reject_add and reject_mul:
        supported = "mixed"
    elif reject_add:
        supported = "multiplicative"
    elif reject_mul:
        supported = "additive"
    else:  # neither rejected: the restricted model with the larger likelihood (smaller LR against mixed)
        supported = "additive" if lr_additive <= lr_multiplicative else "multiplicative"
    return ScatterDiagnostic(
        lr_additive=float(lr_additive),
        p_additive=p_add,
        lr_multiplicative=float(lr_multiplicative),
        p_multiplicative=p_mul,
        supported=supported,
        decided=reject_add or reject_mul,
    )


def _screen_censored(
    x: np.ndarray, m: np.ndarray, censored: np.ndarray, k: float, a_kg: float, b: float
) -> tuple[np.ndarray, str]:
    """Which points to keep: every slip, and the no-slip bounds consistent with the slips' scatter.

    A bound c at x = 1/l is kept if P(m > c) >= `CENSORED_CONSISTENCY_P` under the slips-only fit
    (mean k·x, sd² = a² + (b·k·x)²). Returns the mask of kept points and the note for those left out.
    """
    from scipy import special  # imported on first use (costly import, see model.fit)

    mu = k * x
    sd = np.sqrt(a_kg * a_kg + (b * mu) ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(sd > 0, (m - mu) / sd, np.inf)
    log_p = special.log_ndtr(-z)
    inconsistent = censored & (log_p < math.log(CENSORED_CONSISTENCY_P))
    count = int(inconsistent.sum())
    if not count:
        return np.ones(m.size, dtype=bool), ""
    note = (
        f"{count} no-slip point(s) excluded: each held beyond {float(z[inconsistent].min()):.1f} sd above"
        f" its predicted slip load (P < {CENSORED_CONSISTENCY_P:g} under the slips' scatter): a joint"
        " that held, not a slip beyond the force limit"
    )
    return ~inconsistent, note


def _tobit(
    x: np.ndarray, m: np.ndarray, censored: np.ndarray, alpha: float, beta: float, k_start: float
) -> tuple[float, float, float]:
    """Censored maximum likelihood of k with the scatter's shape held: σ_i = s·√(α + β μ_i²).

    Slips contribute the normal density, censored points P(m > bound). Returns (k, se(k), s·√β): the
    last is the fitted relative sd b when the shape is purely multiplicative (α = 0, β = 1). se
    comes from the observed information of (k, ln s), inflated by √(n/(n − 1)) so that without
    censoring it matches the t-interval's standard error.
    """
    from scipy import optimize, special  # imported on first use (costly import, see model.fit)

    slips = ~censored
    n = m.size

    def shape(k: float) -> np.ndarray:
        mu = k * x
        return np.sqrt(alpha + beta * mu * mu)

    def negloglik(params: np.ndarray) -> float:
        k, log_s = float(params[0]), float(params[1])
        sd = math.exp(log_s) * shape(k)
        z = (m - k * x) / sd
        value = np.sum(np.log(sd[slips]) + 0.5 * z[slips] ** 2)
        # log P(m > bound) = log Φ(−z) = log(½ erfc(z/√2)).
        value -= np.sum(special.log_ndtr(-z[censored]))
        return float(value)

    mu0 = k_start * x
    r0 = (m - mu0)[slips] / shape(k_start)[slips]
    s0 = max(float(np.sqrt(np.mean(r0 * r0))), 1e-9)
    start = np.array([k_start, math.log(s0)])
    result = optimize.minimize(
        negloglik, start, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12}
    )
    k_hat, log_s_hat = float(result.x[0]), float(result.x[1])
    # Observed information by central differences (steps relative to the scale of each parameter).
    steps = np.array([max(abs(k_hat), 1e-12) * 1e-4, 1e-4])
    point = np.array([k_hat, log_s_hat])
    hessian = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            ei = np.eye(2)[i] * steps[i]
            ej = np.eye(2)[j] * steps[j]
            hessian[i, j] = (
                negloglik(point + ei + ej)
                - negloglik(point + ei - ej)
                - negloglik(point - ei + ej)
                + negloglik(point - ei - ej)
            ) / (4 * steps[i] * steps[j])
    try:
        covariance = np.linalg.inv(hessian)
        var_k = float(covariance[0, 0])
    except np.linalg.LinAlgError:
        var_k = math.inf
    se = math.sqrt(var_k * n / (n - 1)) if var_k > 0 else math.inf
    return k_hat, se, math.exp(log_s_hat) * math.sqrt(beta)


def auto_estimate(
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """`auto`: scatter fitted and diagnosed from the data, k weighted by it, censored points by Tobit."""
    level = check_level(level)
    distances, masses, flags = _checked_data(distances_m, masses_kg, censored)
    slips = ~flags
    _need_slips(int(slips.sum()))
    batch = auto_batch(distances[slips], masses[slips][None, :], level)
    diagnostic = diagnose(float(batch.lr_additive[0]), float(batch.lr_multiplicative[0]))
    a, b = float(batch.scatter_a_kg[0]), float(batch.scatter_b[0])
    k, se = float(batch.k[0]), float(batch.se[0])
    keep, note = _screen_censored(1.0 / distances, masses, flags, k, a, b)
    excluded = int((~keep).sum())
    distances, masses, flags = distances[keep], masses[keep], flags[keep]
    n_censored = int(flags.sum())
    if n_censored:
        alpha, beta = a * a, b * b
        norm = math.sqrt(alpha + beta * k * k * float(np.mean(1.0 / distances[~flags]) ** 2))
        k, se, _ = _tobit(1.0 / distances, masses, flags, alpha / norm**2, beta / norm**2, k)
    half = t_quantile(level, masses.size - 1) * se
    return KEstimate(
        "auto",
        diagnostic.supported,
        int(masses.size),
        n_censored,
        k,
        (k - half, k + half),
        se,
        level,
        a,
        b,
        diagnostic,
        excluded,
        note,
    )


def estimate_k(
    estimator: EstimatorName,
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """The estimate of k by the named estimator; `censored[i]` marks masses_kg[i] as a lower bound."""
    name = check_estimator(estimator)
    if name == "paper":
        return paper_estimate(distances_m, masses_kg, censored, level)
    if name == "weighted":
        return weighted_estimate(distances_m, masses_kg, censored, level)
    return auto_estimate(distances_m, masses_kg, censored, level)
