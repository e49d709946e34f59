"""Errors of predicted against measured maximum payloads: the paper's Table IV statistics (docs/model.md §6).

Definitions (the paper's text lost its equations; these reproduce what it reports):
* absolute error `|m_pred − m_meas|` [kg];
* percentage error `100 · |m_pred − m_meas| / m_meas` [%] (relative to the measurement);
* mean and standard deviation of each, the standard deviation with **ddof = 1** (MATLAB `std`,
  which the paper's numbers come from); with a single trial it is NaN;
* the share of trials whose error is **strictly below** each threshold, as a fraction in [0, 1]
  (paper: 80.4 % of percentage errors below 15 %; 85.7 % of absolute errors below 0.15 kg).
Signed errors (prediction minus measurement) are kept too, so a bias is visible.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

STD_DDOF: Final[int] = 1


@dataclass(frozen=True)
class PayloadErrorStats:
    """Table IV statistics of one set of trials (see the module docstring for definitions).

    Attributes:
        n: number of trials.
        percentage_errors: |pred − meas| / meas · 100 per trial [%].
        signed_percentage_errors: (pred − meas) / meas · 100 per trial [%].
        mean_pct, std_pct: mean and standard deviation (ddof = 1) of the percentage errors [%].
        share_below_pct: threshold [%] → fraction of trials with percentage error < threshold.
        absolute_errors_kg: |pred − meas| per trial [kg].
        signed_errors_kg: pred − meas per trial [kg].
        mean_abs_kg, std_abs_kg: mean and standard deviation (ddof = 1) of the absolute errors [kg].
        share_below_abs_kg: threshold [kg] → fraction of trials with absolute error < threshold.
    """

    n: int
    percentage_errors: tuple[float, ...]
    signed_percentage_errors: tuple[float, ...]
    mean_pct: float
    std_pct: float
    share_below_pct: tuple[tuple[float, float], ...]
    absolute_errors_kg: tuple[float, ...]
    signed_errors_kg: tuple[float, ...]
    mean_abs_kg: float
    std_abs_kg: float
    share_below_abs_kg: tuple[tuple[float, float], ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values; threshold keys are written with `%g` ("15", "0.15", "0.2")."""
        return {
            "n": self.n,
            "percentage_errors": list(self.percentage_errors),
            "signed_percentage_errors": list(self.signed_percentage_errors),
            "mean_pct": self.mean_pct,
            "std_pct": self.std_pct,
            "share_below_pct": {f"{t:g}": share for t, share in self.share_below_pct},
            "absolute_errors_kg": list(self.absolute_errors_kg),
            "signed_errors_kg": list(self.signed_errors_kg),
            "mean_abs_kg": self.mean_abs_kg,
            "std_abs_kg": self.std_abs_kg,
            "share_below_abs_kg": {f"{t:g}": share for t, share in self.share_below_abs_kg},
            "std_ddof": STD_DDOF,
        }


def _vector(name: str, values: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1:
        raise ValueError(f"{name}: shape {array.shape}; allowed: a one-dimensional sequence")
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] = {float(array[bad[0]])!r}; allowed: finite")
    return array


def _thresholds(name: str, values: Sequence[float]) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    for v in out:
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} contains {v!r}; allowed: finite and > 0")
    return out


def _mean_std(values: NDArray[np.float64]) -> tuple[float, float]:
    mean = float(values.mean())
    std = float(values.std(ddof=STD_DDOF)) if values.size > STD_DDOF else math.nan
    return mean, std


def _shares(values: NDArray[np.float64], thresholds: tuple[float, ...]) -> tuple[tuple[float, float], ...]:
    return tuple((t, float(np.count_nonzero(values < t)) / values.size) for t in thresholds)


def signed_percentage_error(predicted_kg: float, measured_kg: float) -> float:
    """One trial's error of the predicted payload, (predicted − measured) / measured · 100 [%]."""
    return (predicted_kg - measured_kg) / measured_kg * 100.0


def payload_error_stats(
    predicted_kg: ArrayLike,
    measured_kg: ArrayLike,
    pct_thresholds: Sequence[float] = (15.0,),
    abs_thresholds_kg: Sequence[float] = (0.15, 0.2),
) -> PayloadErrorStats:
    """Table IV statistics of predicted against measured maximum payloads [kg].

    Raises ValueError for empty or unequal inputs, non-finite values, a measured payload <= 0, or a
    threshold that is not finite and > 0.
    """
    predicted = _vector("predicted_kg", predicted_kg)
    measured = _vector("measured_kg", measured_kg)
    if predicted.size != measured.size:
        raise ValueError(f"{predicted.size} predictions but {measured.size} measurements; allowed: one each")
    if predicted.size == 0:
        raise ValueError("no trials; allowed: at least one (predicted, measured) pair")
    nonpositive = np.flatnonzero(measured <= 0)
    if nonpositive.size:
        i = nonpositive[0]
        raise ValueError(f"measured_kg[{i}] = {float(measured[i])!r}; allowed: > 0 kg")
    pct_t = _thresholds("pct_thresholds", pct_thresholds)
    abs_t = _thresholds("abs_thresholds_kg", abs_thresholds_kg)

    signed = predicted - measured
    absolute = np.abs(signed)
    signed_pct = 100.0 * signed / measured
    percentage = np.abs(signed_pct)
    mean_pct, std_pct = _mean_std(percentage)
    mean_abs, std_abs = _mean_std(absolute)
    return PayloadErrorStats(
        n=int(predicted.size),
        percentage_errors=tuple(float(v) for v in percentage),
        signed_percentage_errors=tuple(float(v) for v in signed_pct),
        mean_pct=mean_pct,
        std_pct=std_pct,
        share_below_pct=_shares(percentage, pct_t),
        absolute_errors_kg=tuple(float(v) for v in absolute),
        signed_errors_kg=tuple(float(v) for v in signed),
        mean_abs_kg=mean_abs,
        std_abs_kg=std_abs,
        share_below_abs_kg=_shares(absolute, abs_t),
    )
