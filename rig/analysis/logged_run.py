"""The analysis library: logged runs opened from their MCAP files, with pandas tables (docs/analysis.md).

`open_log(*paths)` reads one run (the parts of a resumed run merged, damaged files read as far as
they go, each problem a `LogWarning`) into a `LoggedRun`; `open_logs(paths)` reads several runs
into `LoggedRuns`, whose tables carry a `run_id` column and whose `refit` pools their trials.

The stages are those of `rig replay` (`rig.analysis.replay_run`): scan and records when a run is
opened; re-detection, refit and the comparisons on first use of what needs them (`trials`,
`replay_result`); the report on request. The tables are DataFrames with units in their column
names; the estimates are typed records (`Refit`). The high-rate tables (`loadcell`, `servos`) are
read from the files when asked for and not kept by the run: hold on to the DataFrame you got.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from model.fit import FitSummary
from model.fit_keys import EstimateSummary
from model.k_estimators import ESTIMATOR_NAMES, EstimatorName
from rig.analysis import redetect as rd
from rig.analysis.refit import BaseMoments, EstimateAgreement, PayloadErrors, joint_estimation_points
from rig.analysis.replay_run import (
    FitSettings,
    RedetectionSummary,
    ReplayResult,
    ScannedRun,
    fit_settings,
    redetect_run,
    replay_scanned,
    scan_run,
)
from rig.analysis.runlog import LogPart
from rig.analysis.trials import trial_table
from rig.errors import InputError
from rig.hw.dxl.transport import BusStats
from rig.hw.seams import LoadCellLineStats
from rig.log.format import schemas
from rig.log.reading.reader import mcap_files
from rig.records import ConfigurationMeasurement, ControlTickStats

_PART_SUFFIX = re.compile(r"\.part[0-9]+$")  # a resumed run's later files: RUN_ID.partN.mcap
LOADCELL_COLUMNS = ("time_s", "force_n", "trial_id", "part")
SERVO_COLUMNS = (
    "time_s",
    "servo_id",
    "role",
    "position_rad",
    "velocity_rad_s",
    "current_a",
    "hardware_error",
    "moving",
    "trial_id",
    "part",
)
CONFIGURATION_COLUMNS = (
    "trial_id",
    "configuration_index",
    "stage",
    "attempt",
    "source",
    "joint",
    "angle_rad",
    "sd_rad",
    "commanded_rad",
    "slipped_joint",
    "time_s",
)
ESTIMATE_COLUMNS = (
    "trial_id",
    "estimator",
    "n",
    "n_censored",
    "k_kg_m",
    "k_low_kg_m",
    "k_high_kg_m",
    "mu_delta0_pa",
    "mu_delta0_low_pa",
    "mu_delta0_high_pa",
    "capacity_nm",
    "capacity_low_nm",
    "capacity_high_nm",
)


class LogWarning(UserWarning):
    """Something in a log could not be read or does not add up; the analysis went on without it."""


@dataclass(frozen=True)
class Refit:
    """A joint-estimation fit m = k/l with its capacity: k, μs·δ0 and capacity with their bounds.

    `summary` is the full record (`rig fit --json` keys, the estimator's choices, the paper's fit).
    """

    estimator: str
    n: int
    level: float
    constant: str
    k_kg_m: float
    k_low_kg_m: float
    k_high_kg_m: float
    mu_delta0_pa: float
    mu_delta0_low_pa: float
    mu_delta0_high_pa: float
    capacity_nm: float
    capacity_low_nm: float
    capacity_high_nm: float
    summary: EstimateSummary = field(repr=False)

    @classmethod
    def of(cls, summary: EstimateSummary) -> Refit:
        """The fit's numbers, named with their units."""
        fit = summary.fit
        return cls(
            estimator=summary.estimate.estimator,
            n=fit.n,
            level=fit.level,
            constant=fit.constant,
            k_kg_m=fit.k,
            k_low_kg_m=fit.k_ci[0],
            k_high_kg_m=fit.k_ci[1],
            mu_delta0_pa=fit.mu_delta0_pa,
            mu_delta0_low_pa=fit.mu_delta0_ci_pa[0],
            mu_delta0_high_pa=fit.mu_delta0_ci_pa[1],
            capacity_nm=fit.capacity_nm,
            capacity_low_nm=fit.capacity_ci_nm[0],
            capacity_high_nm=fit.capacity_ci_nm[1],
            summary=summary,
        )


class LoggedRun:
    """One run read from its MCAP file(s); see the module docstring and docs/analysis.md."""

    def __init__(self, scanned: ScannedRun, detector_overrides: Sequence[str] = ()) -> None:
        self._scanned = scanned
        self._overrides = tuple(detector_overrides)

    @property
    def run_id(self) -> str:
        """The run's id (from its metadata; else the first file's name)."""
        return self._scanned.settings.run_id or _run_name(self.files[0])

    @property
    def protocol(self) -> str | None:
        """The protocol's name, if logged."""
        return self._scanned.settings.protocol_name

    @property
    def files(self) -> list[Path]:
        """The files read, in run order."""
        return [part.path for part in self._scanned.parts]

    @property
    def complete(self) -> bool:
        """Every file finished and undamaged."""
        return all(part.log.complete for part in self._scanned.parts)

    @property
    def truth(self) -> dict[str, Any] | None:
        """The simulator's ground truth (`sim_truth` metadata) of a simulated run, else None."""
        return self._scanned.settings.truth

    @cached_property
    def replay_result(self) -> ReplayResult:
        """Everything `rig replay` finds in the run (re-detected with the detector given at opening)."""
        return replay_scanned(self._scanned, self._overrides)

    @property
    def warnings(self) -> list[str]:
        """What could not be read or does not add up (as `rig replay` lists them)."""
        return list(self.replay_result.warnings)

    @property
    def trials(self) -> pd.DataFrame:
        """One row per trial: the columns of `rig replay --report`'s trials.csv (a copy)."""
        return self.replay_result.table.copy()

    @property
    def estimates(self) -> pd.DataFrame:
        """The online estimate the run logged after each trial (NaN before it had a fit)."""
        rows = []
        for logged in self._scanned.estimates:
            row: dict[str, Any] = {
                "trial_id": logged.trial_id,
                "estimator": logged.estimator,
                "n_censored": logged.n_censored,
            }
            row.update(_fit_columns(logged.fit))
            rows.append(row)
        return _frame(rows, ESTIMATE_COLUMNS, {"trial_id": "Int64", "n": "Int64", "n_censored": "Int64"})

    @property
    def loadcell(self) -> pd.DataFrame:
        """Every load-cell sample: time from the run's start, tension, its trial (NA between trials)."""
        return self._sampled(schemas.LOADCELL, ("force_n",), LOADCELL_COLUMNS)

    @property
    def servos(self) -> pd.DataFrame:
        """Every servo state read: time from the run's start, servo id and role, position, current."""
        names = (
            "servo_id",
            "role",
            "position_rad",
            "velocity_rad_s",
            "current_a",
            "hardware_error",
            "moving",
        )
        return self._sampled(schemas.SERVO_STATE, names, SERVO_COLUMNS)

    @property
    def configurations(self) -> pd.DataFrame:
        """Measured link configurations: one row per measurement and joint (angle, its sd, commanded)."""
        rows: list[dict[str, Any]] = []
        start = self.start_time_ns
        for part in self._scanned.parts:
            measured, _, _ = part.log.records(
                schemas.CONFIGURATION_MEASURED, ConfigurationMeasurement.from_payload
            )
            for measurement in measured:
                rows.extend(_configuration_rows(measurement, start))
        integers = {"trial_id": "Int64", "configuration_index": "Int64", "attempt": "Int64", "joint": "Int64"}
        return _frame(rows, CONFIGURATION_COLUMNS, {**integers, "slipped_joint": "Int64"})

    @property
    def links(self) -> pd.DataFrame:
        """Per trial, the servo bus's exchanges, the load-cell line's counts and the control ticks.

        Columns `trial_id`, then `bus_<count>`, `loadcell_<count>`, `control_<count>` (docs/formats.md
        §7.3, `/rig/trial/links`); NA where a device keeps no counts.
        """
        rows: list[dict[str, Any]] = []
        columns = ["trial_id"]
        for name, kind in (("bus", BusStats), ("loadcell", LoadCellLineStats), ("control", ControlTickStats)):
            columns += [f"{name}_{f.name}" for f in fields(kind)]
        for stats in self._scanned.links:
            row: dict[str, Any] = {"trial_id": stats.trial_id}
            for name, counts in (
                ("bus", stats.bus),
                ("loadcell", stats.loadcell),
                ("control", stats.control),
            ):
                if counts is not None:
                    row.update({f"{name}_{f.name}": getattr(counts, f.name) for f in fields(counts)})
            rows.append(row)
        return _frame(rows, columns, dict.fromkeys(columns, "Int64"))

    @property
    def payload_errors(self) -> PayloadErrors | None:
        """Table IV: the link-validation payload errors (None without link-validation slips)."""
        return self.replay_result.percentage_errors

    @property
    def base_moments(self) -> BaseMoments | None:
        """Table V: the load moment about the base at slip (None without link-validation slips)."""
        return self.replay_result.base_moments

    @property
    def online_agreement(self) -> EstimateAgreement:
        """How far the offline refit (`refit()`) and the run's last online estimate are apart."""
        return self.replay_result.agreement

    @property
    def redetection(self) -> RedetectionSummary:
        """How re-detection with the detector given at opening compares with the logged events."""
        return self.replay_result.redetection_summary()

    def refit(
        self,
        estimator: EstimatorName | None = None,
        constant: str | None = None,
        level: float | None = None,
        *,
        trials: pd.DataFrame | None = None,
        masses: str = "slip_mass_kg",
    ) -> Refit | None:
        """Refit k from the joint-estimation trials (None below 2 slips or without the joint radius).

        Defaults: the run's estimator, constant and level. `trials` (default: `self.trials`) and
        `masses`, the column of slip masses, refit other data: e.g. `trials=run.redetect(...)`,
        `masses="redetected_slip_mass_kg"`.
        """
        return _refit(
            self._fit_settings,
            trials if trials is not None else self.trials,
            estimator,
            constant,
            level,
            masses,
        )

    def redetect(self, **detector_fields: Any) -> pd.DataFrame:
        """The trials table with its `redetection` and `redetected_*` columns from these detector fields.

        Fields are the detector's (docs/model.md §7), e.g. `drop_fraction=0.2`; None disables an
        optional trigger. Without fields: the logged parameters (each trial should give `match`).
        """
        overrides = _assignments(detector_fields)
        rd.validate_overrides(overrides)
        redetected = redetect_run(self._scanned, overrides)
        return trial_table(self._scanned.records, self._scanned.settings, redetected.redetections)

    def report(self, directory: str | os.PathLike[str]) -> list[Path]:
        """Write what `rig replay --report` writes into `directory` (new or empty); returns the files."""
        from rig.analysis.report import check_report_dir, write_report  # matplotlib: only when asked

        check_report_dir(directory)
        return write_report(self.replay_result, directory)

    def json(self) -> dict[str, Any]:
        """The `rig replay --json` object."""
        return self.replay_result.as_json()

    @cached_property
    def _fit_settings(self) -> FitSettings:
        return fit_settings(self._scanned)

    @cached_property
    def start_time_ns(self) -> int:
        """The log time (epoch ns) the tables' `time_s` counts from: the run's first message."""
        firsts = [
            report.first_log_time_ns
            for part in self._scanned.parts
            for report in part.log.reports
            if report.first_log_time_ns is not None
        ]
        return min(firsts) if firsts else 0

    def _sampled(self, topic: str, names: Sequence[str], columns: Sequence[str]) -> pd.DataFrame:
        frames = [self._part_samples(part, topic, names) for part in self._scanned.parts]
        if not frames:
            return pd.DataFrame(columns=list(columns))
        return pd.concat(frames, ignore_index=True)[list(columns)]

    def _part_samples(self, part: LogPart, topic: str, names: Sequence[str]) -> pd.DataFrame:
        frame = part.log.read_all(topic)
        times = frame["log_time_ns"].to_numpy(np.int64)
        out = pd.DataFrame({"time_s": (times - self.start_time_ns) / 1e9})
        for name in names:
            out[name] = frame[name].to_numpy() if name in frame.columns else None
        out["trial_id"] = _trial_ids(times, [r for r in self._scanned.records if r.part is part])
        out["part"] = pd.array([part.name] * len(out), dtype="string")
        return out


class LoggedRuns(Sequence[LoggedRun]):
    """Several runs: their tables stacked with a `run_id` column, and one refit over all their trials."""

    def __init__(self, runs: Iterable[LoggedRun]) -> None:
        self._runs = list(runs)

    def __len__(self) -> int:
        return len(self._runs)

    def __iter__(self) -> Iterator[LoggedRun]:
        return iter(self._runs)

    def __getitem__(self, index: Any) -> Any:
        if isinstance(index, str):
            for run in self._runs:
                if run.run_id == index:
                    return run
            raise KeyError(f"no run {index!r}; runs: {', '.join(r.run_id for r in self._runs)}")
        return self._runs[index]

    @property
    def trials(self) -> pd.DataFrame:
        """Every run's trials, `run_id` first."""
        return _stacked((run.run_id, run.trials) for run in self._runs)

    @property
    def estimates(self) -> pd.DataFrame:
        """Every run's online estimates, `run_id` first."""
        return _stacked((run.run_id, run.estimates) for run in self._runs)

    def refit(
        self,
        estimator: EstimatorName | None = None,
        constant: str | None = None,
        level: float | None = None,
        *,
        trials: pd.DataFrame | None = None,
        masses: str = "slip_mass_kg",
    ) -> Refit | None:
        """One fit over the joint-estimation trials of every run (they must share joint radius and g).

        Defaults: the first run's estimator, constant and level; `trials` and `masses` as in
        `LoggedRun.refit` (a `trials` table here is one with a `run_id` column, as `self.trials`).
        """
        if not self._runs:
            raise InputError("no runs to refit")
        settings = [run._fit_settings for run in self._runs]
        for name in ("radius_m", "g"):
            values = {getattr(s, name) for s in settings}
            if len(values) > 1:
                listed = ", ".join(
                    f"{r.run_id}: {getattr(s, name)}" for r, s in zip(self._runs, settings, strict=True)
                )
                raise InputError(f"runs differ in {name} ({listed}); allowed: runs of one link and rig")
        return _refit(
            settings[0], trials if trials is not None else self.trials, estimator, constant, level, masses
        )


def open_log(
    *paths: str | os.PathLike[str], detector: Mapping[str, Any] | Sequence[str] | None = None
) -> LoggedRun:
    """One run from its MCAP file(s) or their directory: every part of a resumed run, in run order.

    Problems found while reading (a damaged or unfinished file, a lost record) are issued as
    `LogWarning`s and listed in `.warnings`; only a path that is not a rig log raises (InputError).
    `detector`: detector fields for the re-detection behind `.trials`, as a mapping or as
    `rig replay --detector`'s "key=value" strings.
    """
    overrides = _assignments(detector) if isinstance(detector, Mapping) else tuple(detector or ())
    rd.validate_overrides(overrides)
    scanned = scan_run(paths)
    for message in dict.fromkeys([w for part in scanned.parts for w in part.log.warnings] + scanned.warnings):
        warnings.warn(message, LogWarning, stacklevel=2)
    return LoggedRun(scanned, overrides)


def open_logs(paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> LoggedRuns:
    """Several runs: files and directories, grouped into runs by name (`RUN.mcap`, `RUN.partN.mcap`)."""
    groups: dict[tuple[Path, str], list[Path]] = {}
    for path in mcap_files(paths):
        groups.setdefault((path.parent, _run_name(path)), []).append(path)
    return LoggedRuns(open_log(*files) for files in groups.values())


def _assignments(fields: Mapping[str, Any]) -> tuple[str, ...]:
    """Detector fields as `--detector` assignments (None: 'none', which disables an optional trigger)."""
    return tuple(f"{name}={'none' if value is None else value}" for name, value in fields.items())


def _run_name(path: Path) -> str:
    return _PART_SUFFIX.sub("", path.stem)


def _refit(
    settings: FitSettings,
    trials: pd.DataFrame,
    estimator: EstimatorName | None,
    constant: str | None,
    level: float | None,
    masses: str,
) -> Refit | None:
    if estimator is not None and estimator not in ESTIMATOR_NAMES:
        raise InputError(f"estimator {estimator!r}: allowed: {', '.join(ESTIMATOR_NAMES)}")
    if level is not None and not 0 < level < 1:
        raise InputError(f"level {level}: allowed: between 0 and 1 (exclusive)")
    if masses not in trials.columns:
        raise InputError(f"masses {masses!r}: not a column of the trials table")
    chosen = replace(
        settings,
        estimator=estimator or settings.estimator,
        constant=constant or settings.constant,
        level=level or settings.level,
    )
    distances, masses_kg, censored = joint_estimation_points(trials, masses)
    summary = chosen.refit(distances, masses_kg, censored if masses == "slip_mass_kg" else None)
    return None if summary is None else Refit.of(summary)


def _fit_columns(fit: FitSummary | None) -> dict[str, Any]:
    if fit is None:
        return {"n": 0}
    return {
        "n": fit.n,
        "k_kg_m": fit.k,
        "k_low_kg_m": fit.k_ci[0],
        "k_high_kg_m": fit.k_ci[1],
        "mu_delta0_pa": fit.mu_delta0_pa,
        "mu_delta0_low_pa": fit.mu_delta0_ci_pa[0],
        "mu_delta0_high_pa": fit.mu_delta0_ci_pa[1],
        "capacity_nm": fit.capacity_nm,
        "capacity_low_nm": fit.capacity_ci_nm[0],
        "capacity_high_nm": fit.capacity_ci_nm[1],
    }


def _configuration_rows(measured: ConfigurationMeasurement, start_ns: int) -> list[dict[str, Any]]:
    angles = measured.joint_angles_rad or ()
    sds = measured.uncertainty_rad or ()
    commanded = measured.commanded_angles_rad or ()
    count = max(len(angles), len(commanded))
    return [
        {
            "trial_id": measured.trial_id,
            "configuration_index": measured.configuration_index,
            "stage": measured.stage.value,
            "attempt": measured.attempt,
            "source": measured.source.value,
            "joint": j + 1,
            "angle_rad": angles[j] if j < len(angles) else math.nan,
            "sd_rad": sds[j] if j < len(sds) else math.nan,
            "commanded_rad": commanded[j] if j < len(commanded) else math.nan,
            "slipped_joint": measured.slipped_joint,
            "time_s": (measured.measured_time_ns - start_ns) / 1e9,
        }
        for j in range(count)
    ]


def _trial_ids(times_ns: np.ndarray, records: Sequence[Any]) -> pd.arrays.IntegerArray:
    """The trial each log time falls in (start to end inclusive), NA outside every trial."""
    ids = np.zeros(times_ns.size, np.int64)
    inside = np.zeros(times_ns.size, bool)
    for record in records:
        first = np.searchsorted(times_ns, record.result.start_time_ns, "left")
        last = np.searchsorted(times_ns, record.result.end_time_ns, "right")
        ids[first:last] = record.trial_id
        inside[first:last] = True
    return pd.arrays.IntegerArray(ids, ~inside)


def _frame(rows: list[dict[str, Any]], columns: Sequence[str], integers: dict[str, str]) -> pd.DataFrame:
    frame = pd.DataFrame(rows, columns=list(columns))
    for name, dtype in integers.items():
        frame[name] = pd.array(
            [None if v is None or (isinstance(v, float) and math.isnan(v)) else int(v) for v in frame[name]],
            dtype=dtype,
        )
    return frame


def _stacked(tables: Iterable[tuple[str, pd.DataFrame]]) -> pd.DataFrame:
    frames = []
    for run_id, table in tables:
        frames.append(table.assign(run_id=pd.array([run_id] * len(table), dtype="string")))
    if not frames:
        return pd.DataFrame({"run_id": pd.array([], dtype="string")})
    stacked = pd.concat(frames, ignore_index=True)
    return stacked[["run_id", *[c for c in stacked.columns if c != "run_id"]]]
