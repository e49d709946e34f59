"""The trial table: one row per finished trial, rebuilt from `/rig/trial/result`, and its files.

Each `/rig/trial/result` message is decoded into the runner's own `TrialResult` and becomes a
`TrialRecord` that also keeps where the trial's samples are: the part (file) it was logged in, the
log time at which its ramp began (the first `ramp_fast` or `ramp_slow` phase of the trial, which is
the instant from which the live detector was fed), the start of its `unloading` phase, and the
detector's `SlipEvent` the runner logged for it (`/rig/slip`, decoded back into the same record).

`trial_table(records, ...)` turns the records into a DataFrame with a fixed set of columns (units in
the names; nullable integer columns as `Int64`), which `write_trial_table` exports as CSV and
Parquet and `load_trial_table` reads back with the same dtypes.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import pandas as pd

from model.chain import lever_arms_m, planar_transforms
from model.payload_errors import signed_percentage_error
from model.slip_detector import SlipEvent
from rig.analysis.runlog import LogPart, RunSettings
from rig.errors import InputError
from rig.log.format import schemas
from rig.records import (
    SLIP_LIKE,
    ConfigurationMeasurement,
    SlipMessage,
    TrialKind,
    TrialPhase,
    TrialResult,
)
from rig.vocabulary import MeasurementStage

if TYPE_CHECKING:
    from rig.analysis.redetect import Redetection

Record = TypeVar("Record")
RAMP_PHASES = (TrialPhase.RAMP_FAST.value, TrialPhase.RAMP_SLOW.value)
UNLOADING_PHASE = TrialPhase.UNLOADING.value
SLIP_LIKE_OUTCOMES = sorted(o.value for o in SLIP_LIKE)  # the `outcome` values the fit uses
RECOVER_STEP = "recover"  # the runner's step name when it releases the line after a device fault

# Column -> dtype of the trial table (joint angle columns `joint_angle_<i>_rad` are added per joint).
TRIAL_COLUMNS: dict[str, str] = {
    "trial_id": "Int64",
    "kind": "string",
    "part": "string",
    "repeat": "Int64",
    "joint": "Int64",
    "configuration_index": "Int64",
    "distance_m": "float64",
    "outcome": "string",
    "peak_force_n": "float64",
    "slip_mass_kg": "float64",
    "predicted_mass_kg": "float64",
    "percentage_error_pct": "float64",
    "slipped_joint": "Int64",
    "base_lever_arm_m": "float64",
    "base_moment_nm": "float64",
    "start_time_ns": "Int64",
    "end_time_ns": "Int64",
    "ramp_start_ns": "Int64",
    "slip_peak_time_ns": "Int64",
    "slip_detection_time_ns": "Int64",
    "redetection": "string",
    "redetected_peak_force_n": "float64",
    "redetected_slip_mass_kg": "float64",
    "redetected_peak_time_ns": "Int64",
    "redetected_detection_time_ns": "Int64",
    "configuration_source": "string",  # where the measured angles came from (absent: the commanded)
    "bend_corrections": "Int64",  # corrections after bending by forks (the last measurement's attempt)
}
ANGLE_COLUMN = re.compile(r"^joint_angle_(\d+)_rad$")


@dataclass
class TrialRecord:
    """One finished trial: its logged result and where its samples are."""

    part: LogPart
    result: TrialResult
    ramp_start_ns: int | None
    unloading_ns: int | None
    slip: SlipEvent | None
    # Further drops the runner counted after the slip; None if not logged (before the train rule).
    train_drops: int | None = None
    # The last measurement after bending (`/rig/configuration/measured`); None when none was logged.
    configuration: ConfigurationMeasurement | None = None

    @property
    def trial_id(self) -> int:
        """The trial's id (1-based position in the protocol's plan)."""
        return self.result.trial_id

    @property
    def kind(self) -> TrialKind:
        """joint_estimation or link_validation."""
        return self.result.kind

    @property
    def slipped(self) -> bool:
        """Whether the runner recorded a slip."""
        return self.result.slipped

    @property
    def joint_angles_rad(self) -> tuple[float, ...] | None:
        """The trial's (measured, else commanded) configuration."""
        return self.result.joint_angles_rad


def _value(row: pd.Series, name: str) -> Any:
    """A cell as a plain Python value (None for missing)."""
    if name not in row.index:
        return None
    value = row[name]
    if value is None or value is pd.NA:
        return None
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, np.generic):
        return value.item()
    return value


def decoded_messages(
    part: LogPart, topic: str, decode: Callable[[dict[str, Any]], Record], warnings: list[str]
) -> list[Record]:
    """A part's messages of a topic decoded into records, in log order (`RunLog.records`).

    A payload that does not decode (damaged, or of a pre-release log format) is skipped; one warning
    per part and topic counts them and quotes the first problem.
    """
    records, failed, first = part.log.records(topic, decode)
    if failed:
        warnings.append(
            f"{part.name}: {failed} {topic} message{'s' if failed > 1 else ''} could not be decoded "
            f"(first: {first}); skipped"
        )
    return records


def trial_records(parts: Sequence[LogPart], warnings: list[str]) -> list[TrialRecord]:
    """Every `/rig/trial/result` of the run, in part order then log time; duplicates warned and dropped."""
    records: list[TrialRecord] = []
    seen: dict[int, str] = {}
    for part in parts:
        phases = _TrialPhases(part.log.topic(schemas.TRIAL_STATE))
        slips: dict[int, list[SlipMessage]] = {}
        for slip_message in decoded_messages(part, schemas.SLIP, SlipMessage.from_payload, warnings):
            slips.setdefault(slip_message.trial_id, []).append(slip_message)
        measured = _bent_measurements(part, warnings)
        for result in decoded_messages(part, schemas.TRIAL_RESULT, TrialResult.from_payload, warnings):
            trial_id = result.trial_id
            if trial_id in seen:
                warnings.append(
                    f"{part.name}: trial {trial_id} has a second result (first in {seen[trial_id]}); "
                    "the first is kept"
                )
                continue
            seen[trial_id] = part.name
            start, end = result.start_time_ns, result.end_time_ns
            ramp_start, unloading = phases.ramp_window(trial_id, start, end)
            message = _logged_slip(slips.get(trial_id, ()), trial_id, start, end)
            slip = message.event if message is not None else None
            train = message.train_drops if message is not None and "train_k" in message.detector else None
            configuration = measured.get(trial_id)
            records.append(
                TrialRecord(
                    part, result, ramp_start, unloading, slip, train_drops=train, configuration=configuration
                )
            )
            if result.slipped and slip is None:
                warnings.append(
                    f"{part.name}: trial {trial_id}: outcome {result.outcome} but no /rig/slip event logged"
                )
    return records


def _bent_measurements(part: LogPart, warnings: list[str]) -> dict[int, ConfigurationMeasurement]:
    """Each trial's last configuration measured after bending (none where no source measured)."""
    out: dict[int, ConfigurationMeasurement] = {}
    decode = ConfigurationMeasurement.from_payload
    for measurement in decoded_messages(part, schemas.CONFIGURATION_MEASURED, decode, warnings):
        if measurement.stage == MeasurementStage.BENT:
            out[measurement.trial_id] = measurement
    return out


class _TrialPhases:
    """A part's `/rig/trial/state` messages, grouped by trial (each trial's looked at alone)."""

    def __init__(self, states: pd.DataFrame) -> None:
        self.times = states["log_time_ns"].to_numpy() if not states.empty else np.zeros(0, np.int64)
        self.by_trial: dict[int, list[int]] = {}
        if states.empty:
            return
        self.phases = states["phase"].to_numpy(object)
        # A trial repeated after a device fault logs a `recover` step; its result is the last attempt's.
        self.steps = states["step"].to_numpy(object) if "step" in states else np.full(len(states), None)
        for index, trial_id in enumerate(states["trial_id"].tolist()):
            if not _missing(trial_id) and trial_id == int(trial_id):
                self.by_trial.setdefault(int(trial_id), []).append(index)

    def ramp_window(self, trial_id: int, start_ns: int, end_ns: int) -> tuple[int | None, int | None]:
        """Log times of the trial's first ramp phase and of its unloading phase after it (None if absent)."""
        rows = np.asarray(self.by_trial.get(trial_id, ()), np.int64)
        if rows.size == 0:
            return None, None
        times = self.times[rows]
        phases = self.phases[rows]
        mine = (times >= start_ns) & (times <= end_ns)
        recovered = np.flatnonzero(mine & (self.steps[rows] == RECOVER_STEP))
        if recovered.size:
            mine &= times >= times[recovered[-1]]
        ramp_idx = np.flatnonzero(mine & np.isin(phases, RAMP_PHASES))
        if ramp_idx.size == 0:
            return None, None
        ramp_start = int(times[ramp_idx[0]])
        unload_idx = np.flatnonzero(mine & (phases == UNLOADING_PHASE) & (times >= ramp_start))
        return ramp_start, int(times[unload_idx[0]]) if unload_idx.size else None


def _logged_slip(
    slips: Sequence[SlipMessage], trial_id: int, start_ns: int, end_ns: int
) -> SlipMessage | None:
    """The first slip logged for the trial within its time span (`slips`: the part's, or the trial's)."""
    for slip in slips:
        if slip.trial_id == trial_id and start_ns <= slip.event.detection_time_ns <= end_ns:
            return slip
    return None


def base_lever_arm_m(settings: RunSettings, joint_angles_rad: Sequence[float]) -> float | None:
    """Lever arm of the line about the base origin at a planar configuration (None without geometry)."""
    article = settings.article
    if article is None or len(joint_angles_rad) != article.joint_count:
        return None
    transforms = planar_transforms(np.asarray(joint_angles_rad, float), np.asarray(article.segment_lengths_m))
    arms = lever_arms_m(transforms, np.asarray(article.point_m), np.asarray(article.direction))
    return float(arms[0])


def trial_table(
    records: Sequence[TrialRecord],
    settings: RunSettings,
    redetections: Sequence[Redetection] | None = None,
) -> pd.DataFrame:
    """The trial table (columns `TRIAL_COLUMNS` plus one `joint_angle_<i>_rad` per joint).

    `redetections`, one per record in the same order, fill the `redetection` and `redetected_*`
    columns (left empty without them).
    """
    if redetections is not None and len(redetections) != len(records):
        raise ValueError(f"{len(redetections)} re-detections for {len(records)} trials")
    joints = max((len(r.joint_angles_rad or ()) for r in records), default=0)
    rows: list[dict[str, Any]] = []
    for index, record in enumerate(records):
        r = record.result
        peak = r.peak_force_n
        slip_mass = r.slip_mass_kg
        predicted = r.predicted_mass_kg
        pct = None
        if record.slipped and predicted is not None and slip_mass:
            pct = signed_percentage_error(predicted, slip_mass)
        base_arm = base_lever_arm_m(settings, record.joint_angles_rad) if record.joint_angles_rad else None
        base_moment = (
            peak * base_arm if (record.slipped and peak is not None and base_arm is not None) else None
        )
        row: dict[str, Any] = {
            "trial_id": record.trial_id,
            "kind": record.kind.value,
            "part": record.part.name,
            "repeat": r.repeat,
            "joint": r.joint,
            "configuration_index": r.configuration_index,
            "distance_m": r.distance_m,
            "outcome": r.outcome.value,
            "peak_force_n": peak,
            "slip_mass_kg": slip_mass,
            "predicted_mass_kg": predicted,
            "percentage_error_pct": pct,
            "slipped_joint": r.slipped_joint,
            "base_lever_arm_m": base_arm,
            "base_moment_nm": base_moment,
            "start_time_ns": r.start_time_ns,
            "end_time_ns": r.end_time_ns,
            "ramp_start_ns": record.ramp_start_ns,
            "slip_peak_time_ns": record.slip.peak_time_ns if record.slip else None,
            "slip_detection_time_ns": record.slip.detection_time_ns if record.slip else None,
            "configuration_source": record.configuration.source.value if record.configuration else None,
            "bend_corrections": record.configuration.attempt if record.configuration else None,
        }
        if redetections is not None:
            row.update(_redetected_columns(redetections[index], settings.g))
        for j in range(joints):
            angles = record.joint_angles_rad
            row[f"joint_angle_{j + 1}_rad"] = angles[j] if angles is not None and j < len(angles) else None
        rows.append(row)
    columns = {**TRIAL_COLUMNS, **{f"joint_angle_{j + 1}_rad": "float64" for j in range(joints)}}
    # Column by column from the plain values: a DataFrame built from rows would turn an integer
    # column with a gap into float64 and round its epoch nanoseconds.
    frame = pd.DataFrame(
        {name: _column([row.get(name) for row in rows], dtype) for name, dtype in columns.items()}
    )
    return frame.reset_index(drop=True)


def _redetected_columns(found: Redetection, g: float) -> dict[str, Any]:
    event = found.event
    return {
        "redetection": found.status,
        "redetected_peak_force_n": event.peak_force_n if event else None,
        "redetected_slip_mass_kg": event.peak_force_n / g if event else None,
        "redetected_peak_time_ns": event.peak_time_ns if event else None,
        "redetected_detection_time_ns": event.detection_time_ns if event else None,
    }


def _column(values: list[Any], dtype: str) -> pd.api.extensions.ExtensionArray | np.ndarray:
    if dtype == "Int64":
        return pd.array([None if _missing(v) else int(v) for v in values], dtype="Int64")
    if dtype == "float64":
        return np.array([np.nan if _missing(v) else float(v) for v in values], dtype=float)
    return pd.array([None if _missing(v) else str(v) for v in values], dtype="string")


def _with_dtypes(frame: pd.DataFrame) -> pd.DataFrame:
    """The table's dtypes applied to a frame read back from a file (integers read as int64 or Int64)."""
    out = frame.copy()
    for column in out.columns:
        dtype = TRIAL_COLUMNS.get(column) or ("float64" if ANGLE_COLUMN.match(column) else None)
        if dtype is not None:
            out[column] = _column(out[column].tolist(), dtype)
    return out.reset_index(drop=True)


def _missing(value: Any) -> bool:
    return value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value))


def write_trial_table(frame: pd.DataFrame, directory: Path, stem: str = "trials") -> list[Path]:
    """Write `<stem>.csv` and `<stem>.parquet` into `directory`; returns the paths."""
    csv_path = directory / f"{stem}.csv"
    parquet_path = directory / f"{stem}.parquet"
    frame.to_csv(csv_path, index=False)
    frame.to_parquet(parquet_path, index=False, engine="pyarrow")
    return [csv_path, parquet_path]


def load_trial_table(path: str | Path) -> pd.DataFrame:
    """Read a trial table written by `write_trial_table` (CSV or Parquet) with its dtypes."""
    p = Path(path)
    try:
        if p.suffix == ".parquet":
            frame = pd.read_parquet(p, engine="pyarrow")
        else:
            frame = pd.read_csv(p, dtype={n: "Int64" for n, t in TRIAL_COLUMNS.items() if t == "Int64"})
    except (OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read the trial table ({exc})") from None
    return _with_dtypes(frame)


def records_json(frame: pd.DataFrame) -> list[dict[str, Any]]:
    """The table as a list of plain dicts (None for missing, floats exact); joint angles in one list."""
    angle_columns = sorted(
        (c for c in frame.columns if ANGLE_COLUMN.match(c)), key=lambda c: int(c.split("_")[2])
    )
    out = []
    for _, series in frame.iterrows():
        row = {name: _value(series, name) for name in frame.columns if name not in angle_columns}
        angles = [_value(series, c) for c in angle_columns]
        row["joint_angles_rad"] = angles if any(a is not None for a in angles) else None
        out.append(row)
    return out


def slipped_rows(table: pd.DataFrame) -> pd.Series:
    """Which rows of a trial table are slips of the joint under test (`SLIP_LIKE`)."""
    return table["outcome"].isin(SLIP_LIKE_OUTCOMES)
