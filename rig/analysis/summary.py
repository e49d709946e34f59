"""The tables a person reads from a replay, as (headers, rows): shared by the terminal and report.md.

Every header carries its unit; rows hold plain values (None for missing), formatted by the caller
(`rig.cli.output.format_table` for the terminal, `markdown_table` for the report).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import pandas as pd

from rig.analysis.replay import ReplayResult
from rig.vocabulary import TrialKind

Table = tuple[list[str], list[list[Any]]]


def _cell(value: Any) -> Any:
    if value is None or value is pd.NA:
        return None
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def _round(value: Any, digits: int) -> Any:
    value = _cell(value)
    return None if value is None else round(float(value), digits)


def trials_table(result: ReplayResult) -> Table:
    """One row per trial: what was loaded, what slipped, what was predicted, what re-detection found."""
    headers = [
        "trial",
        "kind",
        "distance [m] / config",
        "outcome",
        "peak [N]",
        "slip mass [kg]",
        "predicted [kg]",
        "error [%]",
        "slipped joint",
        "re-detected peak [N]",
        "re-detection",
    ]
    rows = []
    for r in result.table.itertuples():
        if r.kind == TrialKind.JOINT_ESTIMATION:
            where = f"{r.distance_m:.4f}" if _cell(r.distance_m) is not None else None
            kind = "joint est."
        else:
            where = f"config {r.configuration_index}" if _cell(r.configuration_index) is not None else "-"
            kind = "link val."
        rows.append(
            [
                int(r.trial_id),
                kind,
                where,
                r.outcome,
                _round(r.peak_force_n, 4),
                _round(r.slip_mass_kg, 4),
                _round(r.predicted_mass_kg, 4),
                _round(r.percentage_error_pct, 2),
                _cell(r.slipped_joint),
                _round(r.redetected_peak_force_n, 4),
                r.redetection,
            ]
        )
    return headers, rows


def _interval(pair: Sequence[float] | None, digits: int) -> str | None:
    if not pair or any(v is None for v in pair):
        return None
    return f"[{pair[0]:.{digits}g}, {pair[1]:.{digits}g}]"


def estimates_table(result: ReplayResult) -> Table:
    """The offline refit, the last online estimate and the refit of re-detected peaks side by side.

    Each by the run's estimator, and the paper's fit of the same data beside it when that is another.
    """
    headers = [
        "estimate",
        "n",
        "k [kg·m]",
        "k bounds [kg·m]",
        "capacity [N·m]",
        "capacity bounds [N·m]",
        "mu_s·delta0 [Pa]",
        "R²",
        "RMSE [kg]",
    ]
    rows = []
    estimates: list[tuple[str, Any]] = []
    for name, est in (
        ("offline refit (logged peaks)", result.estimate),
        ("online (last logged)", result.online_estimate),
        ("refit of re-detected peaks", result.redetected_estimate),
    ):
        estimator = est.get("estimator") if est else None
        paper = est.get("paper") if est else None
        if estimator in (None, "paper"):
            estimates.append((name, est))
        else:
            estimates += [(f"{name}, {estimator}", est), (f"{name}, paper's fit", paper)]
    for name, est in estimates:
        if not est:
            rows.append([name, None, None, None, None, None, None, None, None])
            continue
        rows.append(
            [
                name,
                est["n"],
                _round(est["k"], 6),
                _interval(est.get("k_ci"), 5),
                _round(est["capacity_nm"], 5),
                _interval(est.get("capacity_ci_nm"), 5),
                _round(est.get("mu_delta0_pa"), 0),
                _round(est.get("r2"), 5),
                _round(est.get("rmse"), 5),
            ]
        )
    return headers, rows


def payload_errors_table(result: ReplayResult) -> Table | None:
    """Table IV: percentage and absolute errors of the predicted payloads."""
    pe = result.percentage_errors
    if not pe:
        return None
    headers = ["statistic", "value"]
    rows: list[list[Any]] = [
        ["link-validation slips", pe["n"]],
        ["mean ± std of percentage errors [%]", f"{pe['mean_pct']:.2f} ± {_fmt(pe['std_pct'], '.2f')}"],
        ["mean ± std of absolute errors [kg]", f"{pe['mean_abs_kg']:.4f} ± {_fmt(pe['std_abs_kg'], '.4f')}"],
    ]
    for threshold, share in pe["share_below_pct"].items():
        rows.append([f"share of percentage errors < {threshold} % [%]", round(100 * share, 1)])
    for threshold, share in pe["share_below_abs_kg"].items():
        rows.append([f"share of absolute errors < {threshold} kg [%]", round(100 * share, 1)])
    return headers, rows


def base_moments_table(result: ReplayResult) -> Table | None:
    """Table V: the load moment about the base at slip."""
    bm = result.base_moments
    if not bm:
        return None
    headers = ["statistic", "value"]
    rows: list[list[Any]] = [
        ["link-validation slips", bm["n"]],
        ["mean ± std of base moment at slip [N·m]", f"{bm['mean_nm']:.4f} ± {_fmt(bm['std_nm'], '.4f')}"],
        ["range [N·m]", f"{bm['min_nm']:.4f} .. {bm['max_nm']:.4f}"],
    ]
    return headers, rows


def _fmt(value: float | None, spec: str) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def markdown_table(table: Table) -> str:
    """A GitHub-flavoured Markdown table; floats with up to 6 significant digits."""
    headers, rows = table

    def cell(value: Any) -> str:
        value = _cell(value)
        if value is None:
            return "–"
        if isinstance(value, float):
            return f"{value:.6g}"
        return str(value).replace("|", "\\|")

    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)
