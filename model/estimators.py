"""Estimators of k in `m = k / l` beyond the paper's fit, behind one interface (see `estimate_k`).

* `paper`: the paper's least squares through the origin with MATLAB cftool bounds (`model.fit`),
  exact and unchanged. It assumes the same scatter at every distance. Censored points (no slip
  before the force limit) are excluded: cftool has no notion of a lower bound.
* `weighted`: the mean of m·l with a Student-t interval; the efficient estimate when the scatter of a
  slip mass is proportional to it (each trial is then one draw of k times a capacity factor). With
  censored points it becomes the censored (Tobit) likelihood under that scatter model.
* `auto`: fits the mixed scatter model sd(m)² = a² + (b·m)² to the data (iteratively reweighted
  least squares on the squared residuals, the Gaussian likelihood's scoring step), weights the fit
  of k by the fitted scatter, gives Student-t bounds with the scale re-estimated from the weighted
  residuals, and reports a likelihood-ratio diagnostic of which scatter model the data support.
  Censored points enter through the Tobit likelihood. docs/model.md §4.2 has the derivations.

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
# Scoring iterations of the scatter fit: it converges in a handful; a fixed count keeps the batch
# version one vectorised loop and the online cost fixed.
SCATTER_ITERATIONS: Final[int] = 12
# A scatter variance below this fraction of the masses' mean square is taken as zero (exact data).
_RELATIVE_FLOOR: Final[float] = 1e-12


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


def _scatter_step(
    r2: np.ndarray, mu2: np.ndarray, weight: np.ndarray, floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One scoring step: weighted least squares of r² on (1, μ²), clipped to a², b² >= 0.

    The Gaussian likelihood's score equations for (a², b²) are exactly this regression with
    weights 1/σ⁴; where the unconstrained solution has a negative component, the best fit on the
    boundary (the other component alone) is taken.
    """
    s0 = weight.sum(axis=1)
    s1 = (weight * mu2).sum(axis=1)
    s2 = (weight * mu2 * mu2).sum(axis=1)
    t0 = (weight * r2).sum(axis=1)
    t1 = (weight * mu2 * r2).sum(axis=1)
    det = s0 * s2 - s1 * s1
    safe = np.where(np.abs(det) > 1e-300, det, 1.0)
    alpha = np.where(np.abs(det) > 1e-300, (s2 * t0 - s1 * t1) / safe, -1.0)
    beta = np.where(np.abs(det) > 1e-300, (s0 * t1 - s1 * t0) / safe, -1.0)
    alpha_only = t0 / s0
    beta_only = t1 / s2
    ok = (alpha >= 0.0) & (beta >= 0.0)
    # On the boundary: whichever one-component fit has the smaller weighted squared error.
    err_a = (weight * (r2 - alpha_only[:, None]) ** 2).sum(axis=1)
    err_b = (weight * (r2 - beta_only[:, None] * mu2) ** 2).sum(axis=1)
    use_a = err_a <= err_b
    alpha = np.where(ok, alpha, np.where(use_a, alpha_only, 0.0))
    beta = np.where(ok, beta, np.where(use_a, 0.0, beta_only))
    alpha = np.maximum(alpha, floor)
    return alpha, np.maximum(beta, 0.0)


@dataclass(frozen=True, slots=True)
class _Core:
    """The weighted fit under the fitted mixed scatter, per data set (arrays of shape (B,))."""

    k: np.ndarray
    se_model: np.ndarray  # √(Σw r²/(n − 1) / Σw x²): exact when the weights are right
    alpha: np.ndarray  # a²
    beta: np.ndarray  # b²
    floor: np.ndarray


def _auto_core(x: np.ndarray, m: np.ndarray) -> _Core:
    """Scatter fit and weighted k for each row of `m` (B, n); `x` = 1/l is (n,) or (B, n)."""
    n = m.shape[1]
    x = np.broadcast_to(x, m.shape)
    xx = x * x
    # Start: least squares (the additive model) for k, and half of the scatter in each component.
    k = (x * m).sum(axis=1) / xx.sum(axis=1)
    mu = k[:, None] * x
    r = m - mu
    floor = np.maximum(np.mean(m * m, axis=1), 1e-300) * _RELATIVE_FLOOR
    var0 = np.maximum((r * r).mean(axis=1), floor)
    alpha = 0.5 * var0
    beta = 0.5 * var0 / np.mean(mu * mu, axis=1).clip(1e-300)
    for _ in range(SCATTER_ITERATIONS):
        w = 1.0 / (alpha[:, None] + beta[:, None] * mu * mu)
        k = (w * x * m).sum(axis=1) / (w * xx).sum(axis=1)
        mu = k[:, None] * x
        r = m - mu
        # Leverage-corrected squared residuals (REML-like): E[r²] = σ²(1 − h) for the weighted fit.
        leverage = w * xx / (w * xx).sum(axis=1, keepdims=True)
        r2 = r * r / np.clip(1.0 - leverage, 1e-3, None)
        alpha, beta = _scatter_step(r2, mu * mu, w * w, floor)
    w = 1.0 / (alpha[:, None] + beta[:, None] * mu * mu)
    info = (w * xx).sum(axis=1)
    k = (w * x * m).sum(axis=1) / info
    r = m - k[:, None] * x
    se_model = np.sqrt((w * r * r).sum(axis=1) / (n - 1) / info)
    return _Core(k=k, se_model=se_model, alpha=alpha, beta=beta, floor=floor)


def _jackknife_se(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Delete-one jackknife standard error of the whole `auto` k (scatter fit included), per row."""
    b, n = m.shape
    if n < 3:
        return np.zeros(b)
    keep = ~np.eye(n, dtype=bool)  # row i: every point but i
    if b * n <= 4096:  # few data sets (online): all n leave-one-out fits in one batch
        x_out = np.broadcast_to(x, m.shape)[:, None, :].repeat(n, axis=1)[:, keep].reshape(b * n, n - 1)
        m_out = m[:, None, :].repeat(n, axis=1)[:, keep].reshape(b * n, n - 1)
        k_out = _auto_core(x_out, m_out).k.reshape(b, n)
    else:  # many data sets of one design (studies): one batch per left-out point
        k_out = np.empty((b, n))
        for i in range(n):
            x_i = x[keep[i]] if x.ndim == 1 else x[:, keep[i]]
            k_out[:, i] = _auto_core(x_i, m[:, keep[i]]).k
    spread = k_out - k_out.mean(axis=1, keepdims=True)
    jack: np.ndarray = np.sqrt((n - 1) / n * (spread * spread).sum(axis=1))
    return jack


def auto_batch(distances_m: np.ndarray, masses_kg: np.ndarray, level: float = DEFAULT_LEVEL) -> AutoBatch:
    """The uncensored `auto` estimate for each row of `masses_kg` (B, n) at `distances_m` (n,).

    se is the larger of the weighted fit's model-based standard error (exact when the fitted
    weights are the true ones) and the delete-one jackknife of the whole estimator (which also sees
    the scatter fit's own variability and a scatter model that does not hold); bounds k ± t_{n−1}·se.
    """
    level = check_level(level)
    x = 1.0 / np.asarray(distances_m, dtype=float)
    m = np.atleast_2d(np.asarray(masses_kg, dtype=float))
    n = x.size
    _need_slips(n)
    core = _auto_core(x, m)
    se = np.maximum(core.se_model, _jackknife_se(x, m))
    lr_add, lr_mult = _likelihood_ratios(x, m, core.alpha, core.beta, core.k, core.floor)
    return AutoBatch(
        k=core.k,
        se=se,
        t=t_quantile(level, n - 1),
        scatter_a_kg=np.sqrt(core.alpha),
        scatter_b=np.sqrt(core.beta),
        lr_additive=lr_add,
        lr_multiplicative=lr_mult,
    )


def _loglik(m: np.ndarray, mu: np.ndarray, variance: np.ndarray) -> np.ndarray:
    value: np.ndarray = -0.5 * (np.log(variance) + (m - mu) ** 2 / variance).sum(axis=1)
    return value


def _likelihood_ratios(
    x: np.ndarray, m: np.ndarray, alpha: np.ndarray, beta: np.ndarray, k: np.ndarray, floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """2(ℓ_mixed − ℓ_additive) and 2(ℓ_mixed − ℓ_multiplicative), each at the models' ML fits."""
    xx = x * x
    # Additive: least squares, σ² = SSE/n.
    k_add = m @ x / xx.sum()
    mu_add = k_add[:, None] * x
    var_add = np.maximum(((m - mu_add) ** 2).mean(axis=1), floor)
    ll_add = _loglik(m, mu_add, np.broadcast_to(var_add[:, None], m.shape))
    # Multiplicative: the mean of m·l, σ_i² = b² μ_i² with b² = mean((r/μ)²).
    k_mul = (m / x).mean(axis=1)
    mu_mul = k_mul[:, None] * x
    rel = np.maximum((((m - mu_mul) / mu_mul) ** 2).mean(axis=1), _RELATIVE_FLOOR)
    ll_mul = _loglik(m, mu_mul, rel[:, None] * mu_mul * mu_mul)
    # Mixed: at the scatter fit (REML-like, so not exactly the ML; both restricted models are
    # special cases of it, so the mixed maximum is at least the larger of theirs).
    mu = k[:, None] * x
    ll_mix = _loglik(m, mu, alpha[:, None] + beta[:, None] * mu * mu)
    ll_mix = np.maximum(ll_mix, np.maximum(ll_add, ll_mul))
    return 2.0 * (ll_mix - ll_add), 2.0 * (ll_mix - ll_mul)


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
        norm = math.sqrt(alpha + beta * k * k * float(np.mean(1.0 / distances[slips]) ** 2))
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
