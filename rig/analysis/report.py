"""The replay report: a directory with `report.md`, PNG figures and the trial table (CSV, Parquet).

Figures (matplotlib, drawn on `Figure` objects with the Agg canvas, no pyplot state):
* `fit.png` — joint-estimation data and the fitted curve m = k/l with 99 % bounds (paper Fig. 7);
* `residuals.png` — residuals of that fit against distance (Fig. 8);
* `payload_by_configuration.png` — measured and predicted payload per configuration (Fig. 11);
* `percentage_errors.png` — histogram of the percentage errors (Fig. 12);
* `estimate_evolution.png` — the online estimate trial by trial with its bounds;
* `force_traces.png` — every trial's tension during its ramp with the detected peak marked; a run
  of more than `TRACES_PER_PAGE` trials gets one page per that many trials (`force_traces_1.png`,
  `force_traces_2.png`, ...), each drawn from its trials' samples alone, saved and let go before
  the next, so that neither the figure nor the samples read for it grow with the run.
A figure whose data the run does not have (no link validation, fewer than 2 slips) is left out
and report.md says why.

The report is written into a hidden temporary directory next to the target and renamed into place
at the end, so a failure never leaves a half-written report; an existing non-empty target is refused.
"""

from __future__ import annotations

import gc
import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from model.fit import t_quantile
from rig.analysis import replay_tables as summary
from rig.analysis.replay_run import ReplayResult
from rig.analysis.samples import loadcell_samples
from rig.analysis.trials import TrialRecord, slipped_rows, write_trial_table
from rig.errors import InputError
from rig.inputs.files import current_umask
from rig.records import TrialKind

DPI = 110
MEASURED_COLOR = "#1f77b4"
PREDICTED_COLOR = "#d62728"
REDETECTED_COLOR = "#ff7f0e"
BAND_COLOR = "#1f77b4"
TRACE_SECONDS_AFTER_UNLOADING = 0.3
TRACE_COLUMNS = 6
TRACES_PER_PAGE = 8 * TRACE_COLUMNS  # trials in one force-traces figure (a page 8 rows high)


def check_report_dir(directory: str | os.PathLike[str]) -> Path:
    """The report directory if it can be created (missing, or an empty directory); else InputError."""
    target = Path(directory)
    if target.exists():
        if not target.is_dir():
            raise InputError(f"--report {target}: exists and is not a directory; allowed: a new directory")
        if any(target.iterdir()):
            raise InputError(f"--report {target}: directory is not empty; allowed: a new or empty directory")
    return target


def write_report(result: ReplayResult, directory: str | os.PathLike[str]) -> list[Path]:
    """Write the report into `directory` (created; see the module docstring); returns the files."""
    target = check_report_dir(directory)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent))
    try:
        names = _write_all(result, staging)
        # mkdtemp makes it private; the report is an ordinary directory
        staging.chmod(0o777 & ~current_umask())
        if target.exists():
            target.rmdir()  # empty (checked above)
        os.rename(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return [target / name for name in names]


def _write_all(result: ReplayResult, out: Path) -> list[str]:
    figures: dict[str, str] = {}  # file name -> caption
    skipped: dict[str, str] = {}  # figure -> why not drawn
    drawers = [
        ("fit.png", _fit_figure),
        ("residuals.png", _residuals_figure),
        ("payload_by_configuration.png", _payload_figure),
        ("percentage_errors.png", _errors_figure),
        ("estimate_evolution.png", _evolution_figure),
    ]
    for name, draw in drawers:
        drawn = draw(result)
        if isinstance(drawn, str):
            skipped[name] = drawn
            continue
        figure, caption = drawn
        _save(figure, out / name)
        figures[name] = caption
    traces = _save_traces(result, out)
    if isinstance(traces, str):
        skipped["force_traces.png"] = traces
    else:
        figures.update(traces)
    table_files = write_trial_table(result.table, out)
    (out / "replay.json").write_text(
        json.dumps(_strict_json(result.as_json()), allow_nan=False, indent=1) + "\n", encoding="utf-8"
    )
    (out / "report.md").write_text(_markdown(result, figures, skipped), encoding="utf-8")
    return ["report.md", "replay.json", *figures, *(p.name for p in table_files)]


def _save(figure: Figure, path: Path) -> None:
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=DPI)


def _strict_json(value: Any) -> Any:
    """Plain JSON values: tuples as lists, NaN and infinities as null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_strict_json(v) for v in value]
    return value


# ---------------------------------------------------------------------------------------------
# Figures


def _joint_data(result: ReplayResult, column: str) -> tuple[np.ndarray, np.ndarray]:
    t = result.table
    rows = t[(t["kind"] == TrialKind.JOINT_ESTIMATION) & t[column].notna() & t["distance_m"].notna()]
    if column == "slip_mass_kg":
        rows = rows[slipped_rows(rows)]
    return rows["distance_m"].to_numpy(float), rows[column].to_numpy(float)


def _fit_figure(result: ReplayResult) -> tuple[Figure, str] | str:
    summary = result.estimate
    if summary is None:
        return "fewer than 2 joint-estimation slips (or no joint radius): no fit"
    est, chosen = summary.fit, summary.estimate
    distances, masses = _joint_data(result, "slip_mass_kg")
    fig = Figure(figsize=(7.5, 5.0), layout="constrained")
    ax = fig.add_subplot()
    span = distances.max() - distances.min()
    grid = np.linspace(
        max(distances.min() - 0.08 * span, 0.4 * distances.min()), distances.max() + 0.08 * span, 300
    )
    k, (k_lo, k_hi) = est.k, est.k_ci
    level_pct = f"{100 * est.level:g} %"
    t = t_quantile(est.level, est.dfe)
    x = 1.0 / grid
    scatter_sd: float | np.ndarray = est.rmse
    if chosen.estimator != "paper" and chosen.scatter_a_kg is not None:
        # The estimator's own scatter model: sd(m)² = a² + (b·m)².
        scatter_sd = np.hypot(chosen.scatter_a_kg, chosen.scatter_b * k * x)
    half_prediction = t * np.sqrt(scatter_sd**2 + (est.se * x) ** 2)
    ax.fill_between(
        grid, k_lo * x, k_hi * x, color=BAND_COLOR, alpha=0.18, label=f"{level_pct} bounds on k/l"
    )
    ax.plot(grid, k * x - half_prediction, "--", color="0.45", lw=1)
    ax.plot(grid, k * x + half_prediction, "--", color="0.45", lw=1, label=f"{level_pct} prediction bounds")
    fit_label = f"fit m = k/l ({chosen.estimator}), k = {k:.4f} kg·m (n = {est.n})"
    ax.plot(grid, k * x, color=BAND_COLOR, lw=2, label=fit_label)
    paper = summary.paper
    if chosen.estimator != "paper" and paper is not None:
        ax.plot(
            grid,
            paper.k * x,
            "-.",
            color="0.25",
            lw=1.2,
            label=f"paper's fit, k = {paper.k:.4f} kg·m [{paper.k_ci[0]:.4f}, {paper.k_ci[1]:.4f}]",
        )
    ax.plot(distances, masses, "o", color="black", ms=5, label="slip mass (logged peaks)")
    re_est = result.redetected_estimate
    if result.detector_overrides and re_est is not None:
        re_d, re_m = _joint_data(result, "redetected_slip_mass_kg")
        ax.plot(re_d, re_m, "s", mfc="none", color=REDETECTED_COLOR, ms=7, label="slip mass (re-detected)")
        ax.plot(
            grid,
            re_est.fit.k * x,
            ":",
            color=REDETECTED_COLOR,
            lw=2,
            label=f"refit, k = {re_est.fit.k:.4f} kg·m",
        )
    ax.set_ylim(0, masses.max() * 1.35)
    ax.set_xlim(grid[0], grid[-1])
    ax.set_xlabel("distance l from the joint centre [m]")
    ax.set_ylabel("slip mass m_s [kg]")
    ax.set_title(
        f"Joint estimation (cf. paper Fig. 7): capacity {est.capacity_nm:.3f} N·m "
        f"[{est.capacity_ci_nm[0]:.3f}, {est.capacity_ci_nm[1]:.3f}]",
        fontsize=10,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    return fig, "Joint-estimation slip masses and the fitted curve m = k/l with bounds (paper Fig. 7)."


def _residuals_figure(result: ReplayResult) -> tuple[Figure, str] | str:
    if result.estimate is None:
        return "no fit, so no residuals"
    est = result.estimate.fit
    distances, masses = _joint_data(result, "slip_mass_kg")
    residuals = masses - est.k / distances
    fig = Figure(figsize=(7.5, 4.0), layout="constrained")
    ax = fig.add_subplot()
    ax.axhline(0, color="black", lw=1)
    ax.axhline(est.rmse, color="0.5", ls="--", lw=1, label=f"± RMSE = {est.rmse:.4f} kg")
    ax.axhline(-est.rmse, color="0.5", ls="--", lw=1)
    ax.vlines(distances, 0, residuals, color=MEASURED_COLOR, lw=1)
    ax.plot(distances, residuals, "o", color=MEASURED_COLOR, ms=5, label="residual m_s − k/l")
    limit = max(np.abs(residuals).max(), est.rmse) * 1.3
    ax.set_ylim(-limit, limit)
    ax.set_xlabel("distance l from the joint centre [m]")
    ax.set_ylabel("residual [kg]")
    ax.set_title(f"Residuals of the fit (cf. paper Fig. 8): SSE {est.sse:.4g} kg², n = {est.n}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig, "Residuals of the joint-estimation fit against distance (paper Fig. 8)."


def _link_rows(result: ReplayResult) -> Any:
    t = result.table
    return t[(t["kind"] == TrialKind.LINK_VALIDATION) & slipped_rows(t) & t["predicted_mass_kg"].notna()]


def _payload_figure(result: ReplayResult) -> tuple[Figure, str] | str:
    rows = _link_rows(result)
    if rows.empty:
        return "no link-validation slips with a prediction"
    by_config = rows["configuration_index"].notna().all()
    x = (rows["configuration_index"] if by_config else rows["trial_id"]).to_numpy(float)
    measured = rows["slip_mass_kg"].to_numpy(float)
    predicted = rows["predicted_mass_kg"].to_numpy(float)
    fig = Figure(figsize=(max(7.5, 0.35 * len(x) + 2), 4.5), layout="constrained")
    ax = fig.add_subplot()
    ax.vlines(x, np.minimum(measured, predicted), np.maximum(measured, predicted), color="0.6", lw=1)
    ax.plot(x, measured, "o", color=MEASURED_COLOR, ms=6, label="measured (slip mass)")
    ax.plot(x, predicted, "x", color=PREDICTED_COLOR, ms=7, mew=2, label="predicted before the trial")
    ax.set_xlabel("configuration" if by_config else "trial")
    ax.set_xticks(np.unique(x))
    ax.set_ylabel("maximum payload [kg]")
    low = min(measured.min(), predicted.min())
    high = max(measured.max(), predicted.max())
    pad = 0.15 * (high - low) + 0.02
    ax.set_ylim(max(0.0, low - pad), high + pad)
    ax.set_title("Link validation: measured vs predicted payload (cf. paper Fig. 11)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig, "Measured and predicted maximum payload per configuration (paper Fig. 11)."


def _errors_figure(result: ReplayResult) -> tuple[Figure, str] | str:
    if result.percentage_errors is None:
        return "no link-validation slips with a prediction"
    pe = result.percentage_errors.stats
    errors = np.asarray(pe.percentage_errors, float)
    fig = Figure(figsize=(7.5, 4.0), layout="constrained")
    ax = fig.add_subplot()
    top = max(20.0, 2.5 * math.ceil(errors.max() / 2.5 + 1))
    ax.hist(errors, bins=list(np.arange(0, top + 2.5, 2.5)), color=MEASURED_COLOR, edgecolor="white")
    for threshold, share in pe.share_below_pct:
        ax.axvline(
            threshold,
            color=PREDICTED_COLOR,
            ls="--",
            lw=1.5,
            label=f"{100 * share:.1f} % of trials below {threshold:g} %",
        )
    ax.set_xlabel("percentage error |predicted − measured| / measured [%]")
    ax.set_ylabel("trials")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    std = pe.std_pct
    std_text = f"{std:.2f}" if std is not None and not math.isnan(std) else "n/a"
    ax.set_title(
        f"Percentage errors (cf. paper Fig. 12): mean {pe.mean_pct:.2f} % ± {std_text} %, n = {pe.n}",
        fontsize=10,
    )
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    return fig, "Histogram of the percentage errors of the predicted payloads (paper Fig. 12)."


def _evolution_figure(result: ReplayResult) -> tuple[Figure, str] | str:
    rows = [(e.trial_id, e.fit) for e in result.estimates if e.fit is not None]
    if not rows:
        return "no online estimate was logged (fewer than 2 joint-estimation slips)"
    joint_rows = [e for e in result.estimates if e.joints]
    fig = Figure(figsize=(8.0, 6.5 if joint_rows else 4.0), layout="constrained")
    axes = fig.subplots(2 if joint_rows else 1, 1, squeeze=False)[:, 0]
    ax = axes[0]
    trial = np.array([trial_id for trial_id, _ in rows], float)
    capacity = np.array([fit.capacity_nm for _, fit in rows], float)
    lo = np.array([fit.capacity_ci_nm[0] for _, fit in rows], float)
    hi = np.array([fit.capacity_ci_nm[1] for _, fit in rows], float)
    level = rows[-1][1].level
    ax.fill_between(
        trial, lo, hi, step="post", color=BAND_COLOR, alpha=0.2, label=f"{100 * level:g} % bounds"
    )
    ax.step(trial, capacity, where="post", color=BAND_COLOR, lw=2, label="online capacity k·g")
    ax.plot(trial, capacity, "o", color=BAND_COLOR, ms=3)
    truth = result.settings.truth
    if truth and truth.get("capacity_nm"):
        ax.axhline(
            truth["capacity_nm"], color="black", ls=":", lw=1.5, label="simulator truth (joint tested)"
        )
    # The first fits (n = 2, 3) have bounds far wider than the data: keep the axis on the estimate.
    settled = capacity[-1]
    spread = max(np.abs(capacity - settled).max(), abs(hi[-1] - lo[-1]))
    ax.set_ylim(max(0.0, settled - 1.5 * spread), settled + 1.5 * spread)
    ax.set_xlim(trial.min() - 0.5, max(trial.max(), *(e.trial_id for e in result.estimates)) + 0.5)
    ax.set_xlabel("after trial")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_ylabel("joint capacity [N·m]")
    ax.set_title("Online estimate trial by trial (joint-estimation fit)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    if joint_rows:
        ax2 = axes[1]
        trials = np.array([e.trial_id for e in joint_rows], float)
        joint_count = len(joint_rows[-1].joints)
        for j in range(joint_count):
            values = np.array(
                [_or_nan(e.joints[j].capacity_nm) if j < len(e.joints) else np.nan for e in joint_rows]
            )
            ax2.plot(trials, values, "-o", ms=2.5, lw=1.2, label=f"joint {j + 1}")
        ax2.set_xlabel("after trial")
        ax2.xaxis.get_major_locator().set_params(integer=True)
        ax2.set_ylabel("joint capacity [N·m]")
        ax2.set_title("Per-joint capacity estimates during link validation", fontsize=10)
        ax2.grid(alpha=0.3)
        ax2.legend(fontsize=7, ncol=4, loc="best")
    return fig, "The online estimate after every trial, with its bounds (and per-joint capacities)."


def _or_nan(value: float | None) -> float:
    return np.nan if value is None else value


def _save_traces(result: ReplayResult, out: Path) -> dict[str, str] | str:
    """Draw the force traces, a page of `TRACES_PER_PAGE` trials at a time; returns name -> caption."""
    records = [r for r in result.records if r.ramp_start_ns is not None]
    if not records:
        return "no trial has a logged ramp"
    by_trial = {int(r.trial_id): r for r in result.table.itertuples()}
    pages = [records[i : i + TRACES_PER_PAGE] for i in range(0, len(records), TRACES_PER_PAGE)]
    saved: dict[str, str] = {}
    for number, page in enumerate(pages, start=1):
        name = "force_traces.png" if len(pages) == 1 else f"force_traces_{number}.png"
        span = "" if len(pages) == 1 else f"trials {page[0].trial_id} to {page[-1].trial_id}"
        figure, caption = _traces_figure(result, page, by_trial, span)
        _save(figure, out / name)
        saved[name] = caption
        # A figure is a web of reference cycles: collect this page before drawing the next, or
        # two pages are held at once (measured: 30 MB more at the peak for 48 trials a page).
        del figure
        gc.collect()
    return saved


def _traces_figure(
    result: ReplayResult, records: list[TrialRecord], by_trial: dict[int, Any], span: str
) -> tuple[Figure, str]:
    """One figure of the force traces of `records` (each with a ramp); `span` names them, if a page."""
    columns = min(TRACE_COLUMNS, len(records))
    rows = math.ceil(len(records) / columns)
    fig = Figure(figsize=(2.6 * columns + 0.6, 2.0 * rows + 0.8), layout="constrained")
    axes = fig.subplots(rows, columns, squeeze=False)
    for index, record in enumerate(records):
        ax = axes[index // columns][index % columns]
        start = record.ramp_start_ns
        assert start is not None  # only trials with a ramp are drawn
        end = record.unloading_ns if record.unloading_ns is not None else record.result.end_time_ns
        end += int(TRACE_SECONDS_AFTER_UNLOADING * 1e9)
        samples = loadcell_samples(record.part.log, start, end)  # this trial's alone
        times, forces = samples.times_ns, samples.forces_n
        lo, hi = np.searchsorted(times, start), np.searchsorted(times, end)
        t_s = (times[lo:hi] - start) / 1e9
        ax.plot(t_s, forces[lo:hi], color="0.25", lw=0.7)
        if record.unloading_ns is not None:
            ax.axvline((record.unloading_ns - start) / 1e9, color="0.6", ls=":", lw=1)
        if record.slip is not None:
            ax.plot(
                (record.slip.peak_time_ns - start) / 1e9,
                record.slip.peak_force_n,
                "v",
                color=PREDICTED_COLOR,
                ms=6,
            )
        row = by_trial.get(record.trial_id)
        if row is not None and result.detector_overrides and not math.isnan(row.redetected_peak_force_n):
            ax.plot(
                (row.redetected_peak_time_ns - start) / 1e9, row.redetected_peak_force_n, "o",
                mfc="none", color=REDETECTED_COLOR, ms=7,
            )  # fmt: skip
        if record.kind == TrialKind.JOINT_ESTIMATION and record.result.distance_m is not None:
            label = f"d = {record.result.distance_m:.3f} m"
        elif row is not None and not pd.isna(row.configuration_index):
            label = f"config {row.configuration_index}"
        else:
            label = record.kind.replace("_", " ")
        peak = f", {record.slip.peak_force_n:.2f} N" if record.slip else ", no slip"
        ax.set_title(f"trial {record.trial_id}: {label}{peak}", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=min(0.0, float(forces[lo:hi].min()) if hi > lo else 0.0))
    for index in range(len(records), rows * columns):
        axes[index // columns][index % columns].set_visible(False)
    fig.supxlabel("time since the ramp started [s]", fontsize=9)
    fig.supylabel("line tension (tare-corrected) [N]", fontsize=9)
    legend = "▼ logged slip peak; dotted line: unloading starts"
    if result.detector_overrides:
        legend += "; ○ re-detected peak"
    which = f"Force traces of {span}" if span else "Force traces of every trial"
    fig.suptitle(f"{which} ({legend})", fontsize=10)
    caption = "Tension during each trial's ramp, with the detected peak marked"
    return fig, f"{caption} ({span})." if span else f"{caption}."


# ---------------------------------------------------------------------------------------------
# report.md


def _outcome_counts(table: pd.DataFrame) -> str:
    """'22 slip-like; 20 slip, 2 no_slip': how the trials ended (slip-like ones feed the fit)."""
    counts = table["outcome"].value_counts()
    each = ", ".join(f"{int(n)} {outcome}" for outcome, n in counts.items())
    return f"{int(slipped_rows(table).sum())} slip-like; {each}" if each else "none"


def _markdown(result: ReplayResult, figures: dict[str, str], skipped: dict[str, str]) -> str:
    s = result.settings
    lines = [f"# Replay of run {s.run_id or '(unknown)'}", ""]
    lines += [
        f"* protocol: {s.protocol_name or 'unknown'}",
        f"* files: {', '.join(p.name for p in result.parts)}",
        "* complete: "
        + ("yes" if result.complete else "no (damaged or unfinished; what could be read is used)"),
        f"* trials: {len(result.table)} ({_outcome_counts(result.table)})",
        f"* g = {s.g:g} m/s², joint radius R = {s.radius_m if s.radius_m is not None else 'unknown'} m",
        "",
    ]
    if result.warnings:
        lines += ["## Warnings", ""] + [f"* {w}" for w in result.warnings] + [""]
    lines += ["## Estimates", "", summary.markdown_table(summary.estimates_table(result)), ""]
    agreement = result.agreement
    if agreement.compared:
        verdict = "agree" if agreement.agree else f"differ in {', '.join(agreement.differing)}"
        lines += [
            f"Offline refit and last online estimate {verdict} "
            f"(largest relative difference {agreement.max_relative_difference:.3g}).",
            "",
        ]
    red = result.redetection_summary()
    params = ", ".join(f"{k}={v}" for k, v in red.detector.to_mapping().items())
    lines += [
        "## Re-detection",
        "",
        f"Detector ({red.source}): {params}.",
        "",
        f"{red.matches} of {red.trials} trials reproduce the logged slip event exactly."
        if red.exact
        else f"{red.matches} of {red.trials} trials give the logged event; the others changed.",
        "",
    ]
    if red.mismatches:
        lines += [f"* trial {m.trial_id} ({m.status}): {m.detail}" for m in red.mismatches] + [""]
    links = summary.links_table(result)
    if links is not None:
        lines += [
            "## Device links per trial",
            "",
            "What the servo bus's exchanges and the load cell's serial line delivered and lost.",
            "",
            summary.markdown_table(links),
            "",
        ]
    table_iv = summary.payload_errors_table(result)
    if table_iv is not None:
        lines += [
            "## Link validation: payload errors (paper Table IV)",
            "",
            summary.markdown_table(table_iv),
            "",
        ]
    table_v = summary.base_moments_table(result)
    if table_v is not None:
        lines += ["## Base load moment at slip (paper Table V)", "", summary.markdown_table(table_v), ""]
    lines += ["## Figures", ""]
    for name, caption in figures.items():
        lines += [f"### {caption}", "", f"![{caption}]({name})", ""]
    for name, why in skipped.items():
        lines += [f"* `{name}` not drawn: {why}."]
    if skipped:
        lines.append("")
    lines += [
        "## Trials",
        "",
        "Full table: [trials.csv](trials.csv), [trials.parquet](trials.parquet).",
        "",
        summary.markdown_table(summary.trials_table(result)),
        "",
    ]
    return "\n".join(lines)
