"""Offline refits and link-validation statistics from a run's trial table.

* `refit(distances, masses, ...)`: the joint-estimation fit `m = k/l` (docs/model.md §4) by the run's
  estimator, with the paper's fit under `paper`, as the `rig fit --json` keys, with the run's level,
  constant, radius and g. The runner's estimate is the same function of the same logged results
  (the paper's fit also keeps the same exact sums), so the offline refit equals the last
  `/rig/estimate` bit for bit; `compare_estimates` measures any difference.
* `payload_errors(table)`: Table IV statistics of predicted against measured payloads over the
  link-validation slips (`model.payload_errors`).
* `base_moments(table)`: Table V, the load moment about the base origin at slip, per trial and per
  configuration, with its mean and standard deviation (ddof = 1, as MATLAB `std`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from model.estimate_summary import summarize_estimate
from model.estimators import EstimatorName
from model.fit import SUMMARY_KEYS
from model.payload_errors import payload_error_stats
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
) -> dict[str, Any] | None:
    """The fit as `rig fit --json` keys (`paper` inside); None below 2 slips or without a radius.

    `censored[i]` marks masses_kg[i] as a no-slip lower bound (the paper's fit leaves those out).
    """
    slips = len(masses_kg) - (sum(bool(c) for c in censored) if censored is not None else 0)
    if slips < 2 or radius_m is None:
        return None
    summary = summarize_estimate(
        estimator, distances_m, masses_kg, censored, level=level, radius_m=radius_m, constant=constant, g=g
    )
    return summary.as_json()


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


def _numbers(value: Any) -> list[float | None]:
    if value is None:
        return [None]
    if isinstance(value, list | tuple | np.ndarray):
        return [None if v is None else float(v) for v in value]
    return [float(value)]


def compare_estimates(offline: Mapping[str, Any] | None, online: Mapping[str, Any] | None) -> dict[str, Any]:
    """How far two `rig fit --json` objects are apart: the largest relative difference of their numbers.

    `agree` is True when every number agrees within `AGREEMENT_RTOL` (relative; NaN/null equal to
    NaN/null) and the constant's name is the same. With either missing, `compared` is False.
    """
    if not offline or not online or online.get("n") in (None, 0):
        return {"compared": False, "agree": None, "max_relative_difference": None, "differing": []}
    worst = 0.0
    differing: list[str] = []
    for key in SUMMARY_KEYS:
        if key == "constant":
            if offline.get(key) != online.get(key):
                differing.append(key)
                worst = math.inf
            continue
        a_values, b_values = _numbers(offline.get(key)), _numbers(online.get(key))
        if len(a_values) != len(b_values):
            differing.append(key)
            worst = math.inf
            continue
        for a, b in zip(a_values, b_values, strict=True):
            if a is None or b is None or math.isnan(a) or math.isnan(b):
                a_missing = a is None or math.isnan(a)
                b_missing = b is None or math.isnan(b)
                if a_missing != b_missing:
                    differing.append(key)
                    worst = math.inf
                continue
            scale = max(abs(a), abs(b))
            rel = 0.0 if a == b else abs(a - b) / scale
            if rel > AGREEMENT_RTOL and key not in differing:
                differing.append(key)
            worst = max(worst, rel)
    return {
        "compared": True,
        "agree": not differing,
        "max_relative_difference": worst,
        "differing": differing,
    }


def _link_slips(table: pd.DataFrame) -> pd.DataFrame:
    return table[(table["kind"] == "link_validation") & slipped_rows(table)]


def payload_errors(table: pd.DataFrame) -> dict[str, Any] | None:
    """Table IV statistics over the link-validation slips with a prediction (None if there are none)."""
    rows = _link_slips(table)
    rows = rows[rows["predicted_mass_kg"].notna() & rows["slip_mass_kg"].notna()]
    if rows.empty:
        return None
    stats = payload_error_stats(
        rows["predicted_mass_kg"].to_numpy(float), rows["slip_mass_kg"].to_numpy(float)
    )
    out = stats.to_dict()
    out["trial_ids"] = [int(v) for v in rows["trial_id"]]
    return out


def _mean_std(values: np.ndarray) -> tuple[float, float]:
    mean = float(values.mean())
    std = float(values.std(ddof=1)) if values.size > 1 else math.nan
    return mean, std


def base_moments(table: pd.DataFrame) -> dict[str, Any] | None:
    """Table V: base moments at slip [N·m] per link-validation trial and per configuration."""
    rows = _link_slips(table)
    rows = rows[rows["base_moment_nm"].notna()]
    if rows.empty:
        return None
    values = rows["base_moment_nm"].to_numpy(float)
    mean, std = _mean_std(values)
    per_trial = [
        {
            "trial_id": int(r.trial_id),
            "configuration_index": None if pd.isna(r.configuration_index) else int(r.configuration_index),
            "peak_force_n": float(r.peak_force_n),
            "base_lever_arm_m": float(r.base_lever_arm_m),
            "base_moment_nm": float(r.base_moment_nm),
        }
        for r in rows.itertuples()
    ]
    per_configuration = []
    if rows["configuration_index"].notna().all():
        for index, group in rows.groupby("configuration_index", sort=True):
            group_values = group["base_moment_nm"].to_numpy(float)
            per_configuration.append(
                {
                    "configuration_index": int(index),
                    "trials": len(group_values),
                    "mean_nm": float(group_values.mean()),
                }
            )
    return {
        "n": int(values.size),
        "mean_nm": mean,
        "std_nm": std,
        "min_nm": float(values.min()),
        "max_nm": float(values.max()),
        "std_ddof": 1,
        "trials": per_trial,
        "configurations": per_configuration,
    }
