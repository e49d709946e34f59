"""The tables a person reads from a replay, as (headers, rows): shared by the terminal and report.md.

Every header carries its unit; rows hold plain values (None for missing), formatted by the caller
(`rig.cli.output.format_table` for the terminal, `markdown_table` for the report).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import pandas as pd

from model.fit import FitSummary
from model.fit_keys import EstimateSummary
from rig.analysis.replay_run import ReplayResult
from rig.records import Estimate
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
    rows: list[list[Any]] = []
    for name, estimator, main, paper in (
        ("offline refit (logged peaks)", *_fits_of_summary(result.estimate)),
        ("online (last logged)", *_fits_of_logged(result.online_estimate)),
        ("refit of re-detected peaks", *_fits_of_summary(result.redetected_estimate)),
    ):
        if estimator in (None, "paper"):
            rows.append(_estimate_row(name, main))
        else:
            rows += [
                _estimate_row(f"{name}, {estimator}", main),
                _estimate_row(f"{name}, paper's fit", paper),
            ]
    return headers, rows


@dataclass(frozen=True)
class _FitRow:
    """The numbers of one row of the estimates table (None where the source does not carry them)."""

    n: int | None
    k: float | None
    k_ci: tuple[float, float] | None
    capacity_nm: float | None
    capacity_ci_nm: tuple[float, float] | None
    mu_delta0_pa: float | None = None
    r2: float | None = None
    rmse: float | None = None

    @classmethod
    def of(cls, fit: FitSummary) -> _FitRow:
        return cls(
            fit.n, fit.k, fit.k_ci, fit.capacity_nm, fit.capacity_ci_nm, fit.mu_delta0_pa, fit.r2, fit.rmse
        )


def _fits_of_summary(summary: EstimateSummary | None) -> tuple[str | None, _FitRow | None, _FitRow | None]:
    """An offline refit's estimator, its fit and the paper's fit beside it."""
    if summary is None:
        return None, None, None
    paper = None if summary.paper is None else _FitRow.of(summary.paper)
    return summary.estimate.estimator, _FitRow.of(summary.fit), paper


def _fits_of_logged(estimate: Estimate | None) -> tuple[str | None, _FitRow | None, _FitRow | None]:
    """A logged estimate's estimator, its fit and the paper's fit it carries (fewer numbers)."""
    if estimate is None or estimate.fit is None:
        return None, None, None
    paper = None
    if estimate.estimator != "paper" and estimate.paper_k is not None:
        paper = _FitRow(
            estimate.paper_n,
            estimate.paper_k,
            estimate.paper_k_ci,
            estimate.paper_capacity_nm,
            estimate.paper_capacity_ci_nm,
            rmse=estimate.paper_rmse,
        )
    return estimate.estimator, _FitRow.of(estimate.fit), paper


def _estimate_row(name: str, fit: _FitRow | None) -> list[Any]:
    if fit is None:
        return [name, None, None, None, None, None, None, None, None]
    return [
        name,
        fit.n,
        _round(fit.k, 6),
        _interval(fit.k_ci, 5),
        _round(fit.capacity_nm, 5),
        _interval(fit.capacity_ci_nm, 5),
        _round(fit.mu_delta0_pa, 0),
        _round(fit.r2, 5),
        _round(fit.rmse, 5),
    ]


def payload_errors_table(result: ReplayResult) -> Table | None:
    """Table IV: percentage and absolute errors of the predicted payloads."""
    if result.percentage_errors is None:
        return None
    pe = result.percentage_errors.stats
    headers = ["statistic", "value"]
    rows: list[list[Any]] = [
        ["link-validation slips", pe.n],
        ["mean ± std of percentage errors [%]", f"{pe.mean_pct:.2f} ± {_fmt(pe.std_pct, '.2f')}"],
        ["mean ± std of absolute errors [kg]", f"{pe.mean_abs_kg:.4f} ± {_fmt(pe.std_abs_kg, '.4f')}"],
    ]
    for threshold, share in pe.share_below_pct:
        rows.append([f"share of percentage errors < {threshold:g} % [%]", round(100 * share, 1)])
    for threshold, share in pe.share_below_abs_kg:
        rows.append([f"share of absolute errors < {threshold:g} kg [%]", round(100 * share, 1)])
    return headers, rows


def base_moments_table(result: ReplayResult) -> Table | None:
    """Table V: the load moment about the base at slip."""
    bm = result.base_moments
    if bm is None:
        return None
    headers = ["statistic", "value"]
    rows: list[list[Any]] = [
        ["link-validation slips", bm.n],
        ["mean ± std of base moment at slip [N·m]", f"{bm.mean_nm:.4f} ± {_fmt(bm.std_nm, '.4f')}"],
        ["range [N·m]", f"{bm.min_nm:.4f} .. {bm.max_nm:.4f}"],
    ]
    return headers, rows


def links_table(result: ReplayResult) -> Table | None:
    """Per trial, what the servo bus and the load-cell line delivered and lost (None for older logs)."""
    if not result.links:
        return None
    headers = [
        "trial",
        "bus operations",
        "retries",
        "timeouts",
        "corrupt replies",
        "failures",
        "reboots",
        "load-cell lines ok",
        "samples missing",
        "checksum failures",
        "garbled lines",
        "samples dropped",
    ]
    rows: list[list[Any]] = []
    for links in result.links:
        bus, lines = links.bus, links.loadcell
        row: list[Any] = [links.trial_id]
        row += (
            [None] * 6
            if bus is None
            else [bus.operations, bus.retries, bus.timeouts, bus.corrupt, bus.failures, bus.reboots]
        )
        row += (
            [None] * 5
            if lines is None
            else [
                lines.lines_ok,
                lines.missing_samples,
                lines.checksum_failures,
                lines.garbled_lines,
                lines.samples_dropped,
            ]
        )
        rows.append(row)
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
