"""`rig replay` without the CLI: read a run's logs, rebuild its trials, re-detect, refit, compare.

`replay(paths, detector_overrides)` returns a `ReplayResult` holding the trial table, the three
estimates (offline refit of the logged results and refit of re-detected peaks as the runner's
`EstimateSummary`, the last online estimate as the `Estimate` record the runner logged), their
agreement, the re-detection outcome per trial, and for link-validation runs the Table IV and
Table V statistics: typed records, turned into JSON only by `as_json()`. Its warnings name, among
others, the trials that lost load-cell samples (`gaps`). `ReplayResult.as_json()` is the
`rig replay --json` object.

Memory: the logs are read once for their low-rate topics (trial states and results, slips,
estimates, link counts: a few records per trial), and each trial's load-cell samples (and, to
re-detect with other parameters, winch states) are then read for that trial alone, re-detected and
let go. What is held is the largest trial's samples plus a summary per trial (its record, its row of
the table), whatever the length of the run (docs/design.md, "Replay").
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import pandas as pd

from model.fit_keys import EstimateSummary
from model.k_estimators import ESTIMATOR_NAMES, EstimatorName
from model.slip_detector import DetectorParams
from rig.analysis import redetect as rd
from rig.analysis.gaps import gap_warning, trial_gaps
from rig.analysis.refit import (
    BaseMoments,
    EstimateAgreement,
    PayloadErrors,
    base_moments,
    compare_estimates,
    joint_estimation_points,
    payload_errors,
    refit,
)
from rig.analysis.runlog import (
    LogPart,
    RunSettings,
    detector_from_slips,
    read_parts,
    require_some_data,
    run_settings,
)
from rig.analysis.samples import trial_samples
from rig.analysis.trials import TrialRecord, decoded_messages, records_json, trial_records, trial_table
from rig.log.format import schemas
from rig.records import Estimate, TrialWireStats
from rig.vocabulary import TrialKind


@dataclass(frozen=True)
class RedetectionSummary:
    """How re-detection compares with the logged events: matches, and the trials that differ."""

    detector: DetectorParams  # the parameters re-detection used
    source: str  # where they came from: "command line", "protocol metadata", ...
    overrides: tuple[str, ...]  # `--detector key=value` assignments
    trials: int
    matches: int
    mismatches: tuple[rd.Redetection, ...]
    by_status: dict[str, int]

    @property
    def exact(self) -> bool:
        """Whether re-detection used the logged parameters (so every trial should match)."""
        return not self.overrides

    def as_json(self) -> dict[str, Any]:
        """The `redetection` object of `rig replay --json`."""
        return {
            "detector": self.detector.to_mapping(),
            "source": self.source,
            "overrides": list(self.overrides),
            "trials": self.trials,
            "matches": self.matches,
            "mismatches": [
                {"trial_id": r.trial_id, "status": r.status, "detail": r.detail} for r in self.mismatches
            ],
            "by_status": self.by_status,
            "exact": self.exact,
        }


@dataclass
class ReplayResult:
    """Everything `rig replay` found in a run (see the module docstring)."""

    parts: list[LogPart]
    settings: RunSettings
    records: list[TrialRecord]
    table: pd.DataFrame
    estimates: list[Estimate]  # the logged /rig/estimate messages, in run order
    estimate: EstimateSummary | None  # the offline refit of the logged peaks
    online_estimate: Estimate | None  # the last logged estimate, if it has a fit
    redetected_estimate: EstimateSummary | None  # the refit of the re-detected peaks
    agreement: EstimateAgreement  # of `estimate` and `online_estimate`
    detector: DetectorParams
    detector_overrides: list[str]
    redetections: list[rd.Redetection]
    percentage_errors: PayloadErrors | None
    base_moments: BaseMoments | None
    warnings: list[str] = field(default_factory=list)
    links: list[TrialWireStats] = field(default_factory=list)  # per trial; logs before 2026-11-27 have none

    @property
    def files(self) -> list[Path]:
        """The files read, in run order."""
        return [p.path for p in self.parts]

    @property
    def complete(self) -> bool:
        """Every file finished and undamaged."""
        return bool(self.parts) and all(p.log.complete for p in self.parts)

    @property
    def has_link_validation(self) -> bool:
        """Whether the run has link-validation trials."""
        return bool((self.table["kind"] == TrialKind.LINK_VALIDATION).any())

    def redetection_summary(self) -> RedetectionSummary:
        """Matches and mismatches of re-detection against the logged events."""
        by_status: dict[str, int] = {}
        for r in self.redetections:
            by_status[r.status] = by_status.get(r.status, 0) + 1
        return RedetectionSummary(
            detector=self.detector,
            source="command line" if self.detector_overrides else self.settings.detector_source,
            overrides=tuple(self.detector_overrides),
            trials=len(self.redetections),
            matches=by_status.get(rd.MATCH, 0),
            mismatches=tuple(r for r in self.redetections if r.status != rd.MATCH),
            by_status=by_status,
        )

    def as_json(self) -> dict[str, Any]:
        """The `rig replay --json` object."""
        out: dict[str, Any] = {
            "files": [str(p) for p in self.files],
            "complete": self.complete,
            "warnings": list(self.warnings),
            "run_id": self.settings.run_id,
            "protocol": self.settings.protocol_name,
            "trials": records_json(self.table),
            "estimate": _json_or_none(self.estimate),
            "online_estimate": online_estimate_json(self.online_estimate),
            "online_agreement": self.agreement.as_json(),
            "redetected_estimate": _json_or_none(self.redetected_estimate),
            "redetection": self.redetection_summary().as_json(),
        }
        if self.links:
            out["links"] = [links.to_payload() for links in self.links]
        if self.has_link_validation:
            out["percentage_errors"] = _json_or_none(self.percentage_errors)
            out["base_moments"] = _json_or_none(self.base_moments)
            joints = self.final_joint_estimates()
            out["joints"] = joints
        if self.settings.truth is not None:
            out["truth"] = self.settings.truth
        return out

    def final_joint_estimates(self) -> list[dict[str, Any]]:
        """The last logged per-joint capacity estimates (link validation), or []."""
        return [j.to_json() for j in self.estimates[-1].joints] if self.estimates else []


@dataclass
class ScannedRun:
    """A run read from its logs, before re-detection: its parts, settings, trials and logged estimates.

    `warnings` are those of reading the settings and the trials; the parts' own (`part.log.warnings`)
    are gathered into the result at the end, when every topic the replay reads has been read.
    """

    parts: list[LogPart]
    settings: RunSettings
    records: list[TrialRecord]
    estimates: list[Estimate]  # the logged /rig/estimate messages, in run order
    links: list[TrialWireStats]  # per trial; logs before 2026-11-27 have none
    warnings: list[str]


@dataclass(frozen=True)
class FitSettings:
    """What a refit of the run's trials uses: the online fit's settings where it logged them."""

    level: float
    constant: str
    radius_m: float | None
    g: float
    estimator: EstimatorName

    def refit(
        self, distances_m: Sequence[float], masses_kg: Sequence[float], censored: Sequence[bool] | None = None
    ) -> EstimateSummary | None:
        """`rig.analysis.refit.refit` with these settings (None below 2 slips or without a radius)."""
        return refit(
            distances_m,
            masses_kg,
            level=self.level,
            constant=self.constant,
            radius_m=self.radius_m,
            g=self.g,
            estimator=self.estimator,
            censored=censored,
        )


@dataclass(frozen=True)
class Redetected:
    """Every trial re-detected with one set of detector parameters, and the sample gaps seen on the way."""

    params: DetectorParams
    overrides: tuple[str, ...]
    redetections: list[rd.Redetection]
    gap_warnings: list[str]


def scan_run(paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> ScannedRun:
    """Stages scan and records: the run's parts, settings and trial records (InputError without rig data)."""
    parts = read_parts(paths)
    require_some_data(parts)
    warnings: list[str] = []
    settings = run_settings(parts, warnings)
    if settings.detector is None:
        settings.detector = detector_from_slips(parts)
        if settings.detector is not None:
            settings.detector_source = "slip events"
        else:
            warnings.append("no detector parameters logged; re-detection uses the detector's defaults")
    records = trial_records(parts, warnings)
    estimates = [
        e for part in parts for e in decoded_messages(part, schemas.ESTIMATE, Estimate.from_payload, warnings)
    ]
    links = [
        link
        for part in parts
        if part.log.message_counts.get(schemas.TRIAL_LINKS)
        for link in decoded_messages(part, schemas.TRIAL_LINKS, TrialWireStats.from_payload, warnings)
    ]
    return ScannedRun(parts, settings, records, estimates, links, warnings)


def redetect_run(run: ScannedRun, detector_overrides: Sequence[str] = ()) -> Redetected:
    """Stage re-detection: each trial's samples read alone, their gaps counted, the detector run again."""
    overrides = tuple(detector_overrides)
    params = rd.detector_params(run.settings.detector, overrides)
    gap_warnings: list[str] = []
    redetections: list[rd.Redetection] = []
    hold_s = run.settings.hold_after_slip_s
    for record in run.records:
        samples = trial_samples(record, hold_s)
        gaps = trial_gaps(record, samples)
        if gaps is not None:
            gap_warnings.append(gap_warning(gaps))
        redetections.append(
            rd.redetect_trial(record, samples, params, exact=not overrides, hold_after_slip_s=hold_s)
        )
        del samples
    return Redetected(params, overrides, redetections, gap_warnings)


def fit_settings(run: ScannedRun) -> FitSettings:
    """The settings of the run's last online fit, else those of its metadata; the run's estimator."""
    online = _online_estimate(run.estimates)
    online_fit = online.fit if online is not None else None
    settings = run.settings
    return FitSettings(
        level=online_fit.level if online_fit and online_fit.level else settings.level,
        constant=online_fit.constant if online_fit and online_fit.constant else settings.constant,
        radius_m=online_fit.radius_m if online_fit and online_fit.radius_m else settings.radius_m,
        g=settings.g,
        estimator=_run_estimator(run.estimates, []),
    )


def replay(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    detector_overrides: Sequence[str] = (),
) -> ReplayResult:
    """Replay a run's MCAP logs (files or directories); see the module docstring.

    Raises InputError for missing or non-MCAP files, bad detector overrides or files with no rig data.
    """
    rd.validate_overrides(detector_overrides)
    return replay_scanned(scan_run(paths), detector_overrides)


def replay_scanned(run: ScannedRun, detector_overrides: Sequence[str] = ()) -> ReplayResult:
    """Stages re-detection and refit over a scanned run: the `ReplayResult` of `replay`."""
    warnings = list(run.warnings)
    redetected = redetect_run(run, detector_overrides)
    warnings.extend(redetected.gap_warnings)
    online = _online_estimate(run.estimates)
    fit = fit_settings(run)
    if run.settings.radius_m is None and fit.radius_m is None:
        warnings.append("joint radius unknown (no rig metadata): no fit")
    warnings.extend(
        f"re-detection of trial {found.trial_id} does not reproduce the log: {found.detail}"
        for found in redetected.redetections
        if found.status == rd.MISMATCH
    )
    table = trial_table(run.records, run.settings, redetected.redetections)
    _run_estimator(run.estimates, warnings)  # only its warning: `fit` holds the estimator

    estimate = fit.refit(*joint_estimation_points(table))
    re_distances, re_masses, _ = joint_estimation_points(table, "redetected_slip_mass_kg")
    redetected_estimate = fit.refit(re_distances, re_masses)
    agreement = compare_estimates(estimate.fit if estimate else None, online.fit if online else None)
    if agreement.compared and not agreement.agree:
        warnings.append(
            "the offline refit differs from the last online estimate in "
            f"{', '.join(agreement.differing)} (max relative difference "
            f"{agreement.max_relative_difference:.3g})"
        )

    all_warnings = [w for part in run.parts for w in part.log.warnings] + warnings
    return ReplayResult(
        parts=run.parts,
        settings=run.settings,
        records=run.records,
        table=table,
        estimates=run.estimates,
        estimate=estimate,
        online_estimate=online,
        redetected_estimate=redetected_estimate,
        agreement=agreement,
        detector=redetected.params,
        detector_overrides=list(redetected.overrides),
        redetections=redetected.redetections,
        percentage_errors=payload_errors(table),
        base_moments=base_moments(table),
        warnings=list(dict.fromkeys(all_warnings)),
        links=run.links,
    )


def _run_estimator(estimates: list[Estimate], warnings: list[str]) -> EstimatorName:
    """The estimator the run used (its last logged estimate says; logs from before say nothing: paper)."""
    name = estimates[-1].estimator if estimates else "paper"
    for known in ESTIMATOR_NAMES:
        if name == known:
            return known
    warnings.append(f"the log names estimator {name!r}, unknown here; refitting with the paper's fit")
    return "paper"


def _online_estimate(estimates: list[Estimate]) -> Estimate | None:
    """The last logged online estimate, if it has a fit."""
    last = estimates[-1] if estimates else None
    return None if last is None or last.fit is None else last


class _AsJson(Protocol):
    def as_json(self) -> dict[str, Any]: ...


def _json_or_none(record: _AsJson | None) -> dict[str, Any] | None:
    return None if record is None else record.as_json()


def online_estimate_json(last: Estimate | None) -> dict[str, Any] | None:
    """A logged online estimate as `rig fit --json` keys (None without one or without a fit).

    With `estimator`, and the paper's fit under `paper` (the keys the log carries) when the run's
    estimator was another one.
    """
    if last is None or last.fit is None:
        return None
    out = {**last.fit.as_json(), "estimator": last.estimator}
    if last.estimator != "paper" and last.paper_k is not None:
        out["paper"] = {
            "n": last.paper_n,
            "k": last.paper_k,
            "k_ci": None if last.paper_k_ci is None else list(last.paper_k_ci),
            "se": last.paper_se,
            "rmse": last.paper_rmse,
            "capacity_nm": last.paper_capacity_nm,
            "capacity_ci_nm": None if last.paper_capacity_ci_nm is None else list(last.paper_capacity_ci_nm),
        }
    return out
