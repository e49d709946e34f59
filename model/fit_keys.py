"""One estimator's fit as the `rig fit --json` keys, with the paper's fit beside it (docs/formats.md §4).

`summarize_estimate` turns a `model.k_estimators.KEstimate` into the same `FitSummary` keys the paper's
fit has always had (so every consumer of those keys keeps working), and keeps the paper's own
`FitSummary` next to it: whichever estimator is chosen, the paper's numbers stay visible.

For an estimator other than `paper`, the keys that describe residuals are those of its k over the
slips (censored points have no residual): SSE = Σ(m − k/l)², SST = Σ(m − m̄)², R² = 1 − SSE/SST,
dfe = n_slips − 1, RMSE = √(SSE/dfe); `se` and the bounds are the estimator's own. For `paper` the
summary is `model.fit`'s, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from model.fit import (
    FitSummary,
    InverseFit,
    capacity_from_fit,
    fit_inverse_distance,
    fit_summary,
)
from model.joint import CapacityConstant
from model.k_estimators import EstimatorName, KEstimate, estimate_k


@dataclass(frozen=True, slots=True)
class EstimateSummary:
    """The chosen estimator's fit (`fit`), what it estimated (`estimate`) and the paper's fit."""

    fit: FitSummary
    estimate: KEstimate
    paper: FitSummary | None  # None when the paper's fit has fewer than 2 slips

    def as_json(self) -> dict[str, Any]:
        """`rig fit --json`: the FitSummary keys of the chosen estimator, then what it chose, then `paper`."""
        est = self.estimate
        diagnostic = est.diagnostic
        return {
            **self.fit.as_json(),
            "estimator": est.estimator,
            "scatter_model": est.scatter_model,
            "n_censored": est.n_censored,
            "n_excluded": est.n_excluded,
            "note": est.note,
            "scatter_a_kg": est.scatter_a_kg,
            "scatter_b": est.scatter_b,
            "diagnostic": None
            if diagnostic is None
            else {
                "test": "likelihood ratio against the mixed scatter model",
                "lr_additive": diagnostic.lr_additive,
                "p_additive": diagnostic.p_additive,
                "lr_multiplicative": diagnostic.lr_multiplicative,
                "p_multiplicative": diagnostic.p_multiplicative,
                "supported": diagnostic.supported,
                "decided": diagnostic.decided,
            },
            "paper": None if self.paper is None else self.paper.as_json(),
        }


def _inverse_fit_of(estimate: KEstimate, distances: np.ndarray, masses: np.ndarray) -> InverseFit:
    """The estimate in `InverseFit`'s shape: residual statistics of its k over the slips given."""
    x = 1.0 / distances
    residuals = masses - estimate.k * x
    sse = float(residuals @ residuals)
    sst = float(((masses - masses.mean()) ** 2).sum())
    dfe = int(masses.size) - 1
    half = estimate.k_ci[1] - estimate.k
    return InverseFit(
        n=estimate.n,
        k=estimate.k,
        k_ci=estimate.k_ci,
        sse=sse,
        sst=sst,
        r2=math.nan if sst == 0.0 else 1.0 - sse / sst,
        rmse=math.sqrt(sse / dfe),
        dfe=dfe,
        se=estimate.se,
        t=half / estimate.se if estimate.se > 0 else math.nan,
        level=estimate.level,
    )


def summarize_estimate(
    estimator: EstimatorName,
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    censored: Sequence[bool] | None,
    *,
    level: float,
    radius_m: float,
    constant: str | float | CapacityConstant,
    g: float,
) -> EstimateSummary:
    """The named estimator's fit with capacity, and the paper's (ValueError below 2 slips)."""
    flags = np.zeros(len(masses_kg), bool) if censored is None else np.asarray(censored, bool)
    distances = np.asarray(distances_m, float)
    masses = np.asarray(masses_kg, float)
    estimate = estimate_k(estimator, distances_m, masses_kg, censored, level)
    slips_d, slips_m = distances[~flags], masses[~flags]
    paper_fit = fit_inverse_distance(slips_d, slips_m, level)
    paper = fit_summary(paper_fit, capacity_from_fit(paper_fit, radius_m, constant, g))
    if estimator == "paper":
        return EstimateSummary(paper, estimate, paper)
    fit = _inverse_fit_of(estimate, slips_d, slips_m)
    return EstimateSummary(fit_summary(fit, capacity_from_fit(fit, radius_m, constant, g)), estimate, paper)
