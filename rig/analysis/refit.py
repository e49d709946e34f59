"""Offline refits and link-validation statistics from a run's trial table.

* `refit(distances, masses, ...)`: the joint-estimation fit `m = k/l` (docs/model.md §4) by the run's
  estimator, with the paper's fit beside it: the `EstimateSummary` the runner makes, with the run's
  level, constant, radius and g. The runner's estimate is the same function of the same logged
  results (the paper's fit also keeps the same exact sums), so the offline refit equals the last
  `/rig/estimate` bit for bit; `compare_estimates` measures any difference (`EstimateAgreement`).
* `payload_errors(table)`: Table IV statistics of predicted against measured payloads over the
  link-validation slips (`model.payload_errors`), as `PayloadErrors`.
* `base_moments(table)`: Table V, the load moment about the base origin at slip, per trial and per
  configuration, with its mean and standard deviation (ddof = 1, as MATLAB `std`), as `BaseMoments`.

Each record's `as_json()` is its part of the `rig replay --json` object.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import pandas as pd

from model.fit import FitSummary
from model.fit_keys import EstimateSummary, summarize_estimate
from model.k_estimators import EstimatorName
from model.payload_errors import PayloadErrorStats, payload_error_stats
from rig.analysis.trials import slipped_rows
from rig.vocabulary import TrialKind

AGREEMENT_RTOL = 1e-9


def refit(
    distances_m: Sequence[float],
    masses_kg: Sequence[float],
    *,
    level: float,
    constant: str,
    radius_m: float | None,
    g: float,
    estimator: EstimatorName = "paper",
    censored: Sequence[bool] | None = None,
) -> EstimateSummary | None:
    """The fit (the paper's beside it), as the runner makes it; None below 2 slips or without a radius.

    `censored[i]` marks masses_kg[i] as a no-slip lower bound (the paper's fit leaves those out).
    """
    slips = len(masses_kg) - (sum(bool(c) for c in censored) if censored is not None else 0)
    if slips < 2 or radius_m is None:
        return None
    return summarize_estimate(
        estimator, distances_m, masses_kg, censored, level=level, radius_m=radius_m, constant=constant, g=g
    )


def joint_estimation_pairs(
    table: pd.DataFrame, mass_column: str = "slip_mass_kg"
) -> tuple[list[float], list[float], list[int]]:
    """Distances, masses and trial ids of the joint-estimation slips with a mass in `mass_column`."""
    rows = table[
        (table["kind"] == TrialKind.JOINT_ESTIMATION)
        & table[mass_column].notna()
        & table["distance_m"].notna()
    ]
    if mass_column == "slip_mass_kg":
        rows = rows[slipped_rows(rows)]
    return (
        [float(v) for v in rows["distance_m"]],
        [float(v) for v in rows[mass_column]],
        [int(v) for v in rows["trial_id"]],
    )


def joint_estimation_points(
    table: pd.DataFrame, mass_column: str = "slip_mass_kg"
) -> tuple[list[float], list[float], list[bool]]:
    """Distances, masses and censoring flags of the joint-estimation trials a fit uses, in trial order.

    Slips, and (logged peaks only) no-slip trials as lower bounds: the highest load held.
    """
    distances, masses, ids = joint_estimation_pairs(table, mass_column)
    points = [(i, d, m, False) for i, d, m in zip(ids, distances, masses, strict=True)]
    if mass_column == "slip_mass_kg":
        rows = table[
            (table["kind"] == TrialKind.JOINT_ESTIMATION)
            & (table["outcome"] == "no_slip")
            & table[mass_column].notna()
            & table["distance_m"].notna()
        ]
        points += [
            (int(i), float(d), float(m), True)
            for i, d, m in zip(rows["trial_id"], rows["distance_m"], rows[mass_column], strict=True)
        ]
    points.sort(key=lambda p: p[0])
    return [p[1] for p in points], [p[2] for p in points], [p[3] for p in points]


def _numbers(value: float | tuple[float, float]) -> list[float]:
    return [float(v) for v in value] if isinstance(value, tuple) else [float(value)]


@dataclass(frozen=True)
class EstimateAgreement:
    """How far the offline refit and the last online estimate are apart (`compare_estimates`)."""

    compared: bool  # False when either is missing
    agree: bool | None = None
    max_relative_difference: float | None = None
    differing: tuple[str, ...] = ()  # the `rig fit --json` keys that differ

    def as_json(self) -> dict[str, Any]:
        """The `online_agreement` object of `rig replay --json`."""
        return {
            "compared": self.compared,
            "agree": self.agree,
            "max_relative_difference": self.max_relative_difference,
            "differing": list(self.differing),
        }


def compare_estimates(offline: FitSummary | None, online: FitSummary | None) -> EstimateAgreement:
    """How far two fits are apart: the largest relative difference of their numbers.

    `agree` is True when every number agrees within `AGREEMENT_RTOL` (relative; NaN equal to NaN)
    and the constant's name is the same. With either missing (or an online fit of no trials),
    `compared` is False. `differing` names the `rig fit --json` keys that differ.
    """
    if offline is None or online is None or online.n == 0:
        return EstimateAgreement(compared=False)
    worst = 0.0
    differing: list[str] = []
    for key in (f.name for f in fields(FitSummary)):
        a_value, b_value = getattr(offline, key), getattr(online, key)
        if key == "constant":
            if a_value != b_value:
                differing.append(key)
                worst = math.inf
            continue
        for a, b in zip(_numbers(a_value), _numbers(b_value), strict=True):
            if math.isnan(a) or math.isnan(b):
                if math.isnan(a) != math.isnan(b):
                    differing.append(key)
                    worst = math.inf
                continue
            scale = max(abs(a), abs(b))
            rel = 0.0 if a == b else abs(a - b) / scale
            if rel > AGREEMENT_RTOL and key not in differing:
                differing.append(key)
            worst = max(worst, rel)
    return EstimateAgreement(
        compared=True, agree=not differing, max_relative_difference=worst, differing=tuple(differing)
    )


def _link_slips(table: pd.DataFrame) -> pd.DataFrame:
    return table[(table["kind"] == "link_validation") & slipped_rows(table)]


@dataclass(frozen=True)
class PayloadErrors:
    """Table IV: the payload error statistics and the trials they are over."""

    stats: PayloadErrorStats
    trial_ids: tuple[int, ...]

    def as_json(self) -> dict[str, Any]:
        """The `percentage_errors` object of `rig replay --json`."""
        return {**self.stats.to_dict(), "trial_ids": list(self.trial_ids)}


def payload_errors(table: pd.DataFrame) -> PayloadErrors | None:
    """Table IV statistics over the link-validation slips with a prediction (None if there are none)."""
    rows = _link_slips(table)
    rows = rows[rows["predicted_mass_kg"].notna() & rows["slip_mass_kg"].notna()]
    if rows.empty:
        return None
    stats = payload_error_stats(
        rows["predicted_mass_kg"].to_numpy(float), rows["slip_mass_kg"].to_numpy(float)
    )
    return PayloadErrors(stats, tuple(int(v) for v in rows["trial_id"]))


def _mean_std(values: np.ndarray) -> tuple[float, float]:
    mean = float(values.mean())
    std = float(values.std(ddof=1)) if values.size > 1 else math.nan
    return mean, std


@dataclass(frozen=True)
class TrialBaseMoment:
    """One link-validation slip's load moment about the base."""

    trial_id: int
    configuration_index: int | None
    peak_force_n: float
    base_lever_arm_m: float
    base_moment_nm: float


@dataclass(frozen=True)
class ConfigurationBaseMoment:
    """The mean base moment at slip over one configuration's trials."""

    configuration_index: int
    trials: int
    mean_nm: float


@dataclass(frozen=True)
class BaseMoments:
    """Table V: the load moment about the base at slip, per trial and per configuration [N·m]."""

    n: int
    mean_nm: float
    std_nm: float  # ddof = 1 (NaN for one slip)
    min_nm: float
    max_nm: float
    trials: tuple[TrialBaseMoment, ...]
    configurations: tuple[ConfigurationBaseMoment, ...]  # empty when a trial has no configuration

    def as_json(self) -> dict[str, Any]:
        """The `base_moments` object of `rig replay --json`."""
        return {
            "n": self.n,
            "mean_nm": self.mean_nm,
            "std_nm": self.std_nm,
            "min_nm": self.min_nm,
            "max_nm": self.max_nm,
            "std_ddof": 1,
            "trials": [vars(t) for t in self.trials],
            "configurations": [vars(c) for c in self.configurations],
        }


def base_moments(table: pd.DataFrame) -> BaseMoments | None:
    """Table V: base moments at slip [N·m] per link-validation trial and per configuration."""
    rows = _link_slips(table)
    rows = rows[rows["base_moment_nm"].notna()]
    if rows.empty:
        return None
    values = rows["base_moment_nm"].to_numpy(float)
    mean, std = _mean_std(values)
    per_trial = tuple(
        TrialBaseMoment(
            trial_id=int(r.trial_id),
            configuration_index=None if pd.isna(r.configuration_index) else int(r.configuration_index),
            peak_force_n=float(r.peak_force_n),
            base_lever_arm_m=float(r.base_lever_arm_m),
            base_moment_nm=float(r.base_moment_nm),
        )
        for r in rows.itertuples()
    )
    per_configuration: list[ConfigurationBaseMoment] = []
    if rows["configuration_index"].notna().all():
        for index, group in rows.groupby("configuration_index", sort=True):
            group_values = group["base_moment_nm"].to_numpy(float)
            per_configuration.append(
                ConfigurationBaseMoment(int(index), len(group_values), float(group_values.mean()))
            )
    return BaseMoments(
        n=int(values.size),
        mean_nm=mean,
        std_nm=std,
        min_nm=float(values.min()),
        max_nm=float(values.max()),
        trials=per_trial,
        configurations=tuple(per_configuration),
    )
