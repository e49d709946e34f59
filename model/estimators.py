"""Estimators of k in `m = k / l` beyond the paper's fit, behind one interface (see `estimate_k`).

* `paper`: the paper's least squares through the origin with MATLAB cftool bounds (`model.fit`),
  exact and unchanged. It assumes the same scatter at every distance.
* `weighted`: the mean of m·l with a Student-t interval; the efficient estimate when the scatter of a
  slip mass is proportional to it (each trial is then one draw of k times a capacity factor).
* `auto`: chooses the scatter model from the data (see the function's docstring).

Every estimator takes the same data (distances, masses, and which masses are only lower bounds,
i.e. no slip before the force limit) and returns a `KEstimate`.
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


def check_estimator(name: str) -> EstimatorName:
    """`name` as an estimator name; ValueError listing the allowed ones otherwise."""
    for allowed in ESTIMATOR_NAMES:
        if name == allowed:
            return allowed
    raise ValueError(f"estimator {name!r}; allowed: {', '.join(ESTIMATOR_NAMES)}")


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


def paper_estimate(
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """The paper's fit over the slips only (censored points are excluded: cftool has no such notion)."""
    distances, masses, flags = _checked_data(distances_m, masses_kg, censored)
    fit = fit_inverse_distance(distances[~flags], masses[~flags], level)
    return KEstimate("paper", "additive", fit.n, 0, fit.k, fit.k_ci, fit.se, fit.level, fit.rmse, 0.0)


def weighted_estimate(
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """Mean of m·l with a Student-t interval on n − 1 degrees of freedom (censored points excluded)."""
    level = check_level(level)
    distances, masses, flags = _checked_data(distances_m, masses_kg, censored)
    products = distances[~flags] * masses[~flags]
    n = int(products.size)
    if n < 2:
        raise ValueError(f"{n} slip(s); allowed: at least 2 for a fit")
    k = float(products.mean())
    se = float(products.std(ddof=1)) / math.sqrt(n)
    half = t_quantile(level, n - 1) * se
    relative_sd = float(products.std(ddof=1)) / k if k != 0.0 else math.inf
    return KEstimate("weighted", "multiplicative", n, 0, k, (k - half, k + half), se, level, 0.0, relative_sd)


def estimate_k(
    estimator: EstimatorName,
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None = None,
    level: float = DEFAULT_LEVEL,
) -> KEstimate:
    """The estimate of k by the named estimator; `censored[i]` marks masses_kg[i] as a lower bound.

    `auto` is, for now, the weighted estimate labelled as such; the scatter-model selection replaces it.
    """
    name = check_estimator(estimator)
    if name == "paper":
        return paper_estimate(distances_m, masses_kg, censored, level)
    weighted = weighted_estimate(distances_m, masses_kg, censored, level)
    if name == "weighted":
        return weighted
    w = weighted
    return KEstimate("auto", w.scatter_model, w.n, 0, w.k, w.k_ci, w.se, level, w.scatter_a_kg, w.scatter_b)
