"""What a run produces, as typed records: one frozen dataclass per thing, the single source of its shapes.

Each record is built once by the runner and then shown in several places: the MCAP payload
(`to_payload`, whose JSON Schema `rig.log.format.schemas` derives from the record's fields), the run
journal and `rig run --json` (`TrialResult.to_json`), the progress line (`Estimate.text`), and
replay, which decodes the logged payload back into the very same record (`from_payload`).

Payload conventions: a record's fields appear under their own names, except that a time field
`*_time_ns` (epoch ns, an attribute exact for Python) appears only as a `{sec, nsec}` timestamp
named without the suffix (`start_time_ns` → `start`): Foxglove's time type, and no payload integer
beyond 2^53 for JavaScript readers. A missing value (None, a non-finite number) is an absent field,
not null: the JSON Schema readers of Foxglove and Lichtblick accept one type per field
(`rig.log.format.viewer_schema`). Decoders read the payloads of the current log format
(`rig.log.format.log_format`); in a payload read back from a table, a missing value is None.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from enum import IntEnum, StrEnum
from typing import Any

from model.fit import SUMMARY_KEYS, FitSummary, nonnegative_bounds
from model.slip_detector import SlipEvent, SlipEventKind
from rig.hw.dxl.transport import BusStats
from rig.hw.seams import LoadCellLineStats
from rig.vocabulary import SLIP_LIKE, ConfigurationSourceKind, MeasurementStage, TrialKind, TrialOutcome

NS_PER_S = 1_000_000_000


class TrialPhase(StrEnum):
    """Phases of the runner's state machine, as logged on `/rig/trial/state`."""

    IDLE = "idle"
    CONNECTING = "connecting"
    TARING = "taring"
    BENDING = "bending"
    PROMPTING = "prompting"
    RAMP_FAST = "ramp_fast"
    RAMP_SLOW = "ramp_slow"
    UNLOADING = "unloading"
    RESETTING = "resetting"
    PAUSING = "pausing"
    DONE = "done"
    ABORTED = "aborted"
    FAULTED = "faulted"


class ServoCommandName(StrEnum):
    """What a logged servo command set."""

    GOAL_POSITION = "goal_position"
    GOAL_CURRENT = "goal_current"
    GOAL_VELOCITY = "goal_velocity"
    PROFILE_VELOCITY = "profile_velocity"
    PROFILE_ACCELERATION = "profile_acceleration"
    TORQUE = "torque"
    MODE = "mode"
    REBOOT = "reboot"


class LogLevel(IntEnum):
    """`foxglove.Log` levels."""

    UNKNOWN = 0
    DEBUG = 1
    INFO = 2
    WARNING = 3
    ERROR = 4
    FATAL = 5


# ---------------------------------------------------------------------------------------------
# Value coercion shared by the encoders


def stamp(time_ns: int) -> dict[str, int]:
    """Epoch nanoseconds as a `{sec, nsec}` timestamp (foxglove.Timestamp)."""
    t = integer(time_ns, "time_ns")
    if t < 0:
        raise ValueError(f"time_ns: {t} is before the epoch")
    sec, nsec = divmod(t, NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def stamp_name(time_field: str) -> str:
    """The payload name of an epoch-ns field: `start_time_ns` → `start`."""
    return time_field.removesuffix("_time_ns")


def time_ns_from_payload(payload: Mapping[str, Any], time_field: str) -> int:
    """An epoch-ns field from a payload, from its `{sec, nsec}` stamp.

    KeyError if it is not there, ValueError naming the field if the value is not a timestamp.
    """
    name = stamp_name(time_field)
    value = payload.get(name)
    if value is None:
        raise KeyError(name)
    if not isinstance(value, Mapping):
        raise ValueError(f"{name}: {value!r} is not a {{sec, nsec}} timestamp")
    sec = integer(value.get("sec"), f"{name}.sec")
    nsec = integer(value.get("nsec"), f"{name}.nsec")
    if sec < 0 or not 0 <= nsec < NS_PER_S:
        raise ValueError(f"{name}: {{sec: {sec}, nsec: {nsec}}} is not a timestamp (nsec in [0, 1e9))")
    return sec * NS_PER_S + nsec


def finite_number(value: Any, name: str) -> float:
    """A finite number as a plain float; ValueError naming `name` otherwise."""
    if value is None or isinstance(value, bool):
        raise ValueError(f"{name}: {value!r} is not a number")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name}: {x} is not a finite number")
    return x


def number_or_none(value: Any, name: str) -> float | None:
    """A nullable number as a plain float: None and non-finite values become None (JSON null)."""
    if value is None:
        return None
    if isinstance(value, bool):
        raise ValueError(f"{name}: {value!r} is not a number")
    x = float(value)
    return x if math.isfinite(x) else None


def integer(value: Any, name: str) -> int:
    """An integer (numpy ones too) as a plain int; ValueError naming `name` otherwise."""
    if value is None or isinstance(value, bool):
        raise ValueError(f"{name}: {value!r} is not an integer")
    try:
        return operator.index(value)
    except TypeError:
        raise ValueError(f"{name}: {value!r} is not an integer") from None


def integer_or_none(value: Any, name: str) -> int | None:
    """`integer`, or None."""
    return None if value is None else integer(value, name)


def present(payload: dict[str, Any]) -> dict[str, Any]:
    """A payload without its None values: a missing value is an absent field (module docstring)."""
    return {key: value for key, value in payload.items() if value is not None}


def _numbers_or_none(values: Sequence[Any] | None, name: str) -> list[float] | None:
    if values is None:
        return None
    return [finite_number(v, f"{name}[{i}]") for i, v in enumerate(values)]


def _tuple_or_none(values: Sequence[Any] | None) -> tuple[float, ...] | None:
    return None if values is None else tuple(float(v) for v in values)


# ---------------------------------------------------------------------------------------------
# Records


@dataclass(frozen=True, slots=True)
class ServoCommand:
    """A command sent to a servo (logged at the time it was sent)."""

    servo_id: int
    role: str
    command: ServoCommandName
    value: float | None  # setpoint in `unit`; None for reboot
    unit: str  # e.g. rad, A, rad/s, bool, mode; empty if none

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/servo/command` payload (no `value` for a reboot)."""
        return present(
            {
                "servo_id": integer(self.servo_id, "servo_id"),
                "role": str(self.role),
                "command": ServoCommandName(self.command).value,
                "value": number_or_none(self.value, "value"),
                "unit": str(self.unit),
            }
        )

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> ServoCommand:
        """Decode a `/rig/servo/command` payload."""
        return cls(
            servo_id=integer(payload["servo_id"], "servo_id"),
            role=str(payload["role"]),
            command=ServoCommandName(payload["command"]),
            value=number_or_none(payload.get("value"), "value"),
            unit=str(payload.get("unit", "")),
        )


@dataclass(frozen=True, slots=True)
class TrialState:
    """A phase change of the runner (`trial_id` is None outside trials)."""

    trial_id: int | None
    phase: TrialPhase
    step: str | None = None

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/trial/state` payload (no `trial_id` outside trials, no `step` outside steps)."""
        return present(
            {
                "trial_id": integer_or_none(self.trial_id, "trial_id"),
                "phase": TrialPhase(self.phase).value,
                "step": None if self.step is None else str(self.step),
            }
        )

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> TrialState:
        """Decode a `/rig/trial/state` payload."""
        return cls(
            trial_id=integer_or_none(payload.get("trial_id"), "trial_id"),
            phase=TrialPhase(payload["phase"]),
            step=payload.get("step"),
        )


@dataclass(frozen=True, slots=True)
class SlipMessage:
    """A slip the detector reported during a trial: the detector's own `SlipEvent` and its context."""

    trial_id: int
    event: SlipEvent
    detector: Mapping[str, float | None]  # the detector's parameters by name
    joint: int | None = None  # 1-based joint that slipped, if the configuration source knows
    train_drops: int = 0  # further drops in the hold after the event (>= 1: a stick-slip train)

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/slip` payload: the event's fields inline, with the trial, detector and joint.

        Detector parameters that are unset (None) and an unknown joint are left out.
        """
        e = self.event
        detector = {str(k): number_or_none(v, f"detector.{k}") for k, v in self.detector.items()}
        return present(
            {
                "trial_id": integer(self.trial_id, "trial_id"),
                "onset": stamp(e.onset_time_ns),
                "detection": stamp(e.detection_time_ns),
                "peak": stamp(e.peak_time_ns),
                "peak_force_n": finite_number(e.peak_force_n, "peak_force_n"),
                "force_after_n": finite_number(e.force_after_n, "force_after_n"),
                "drop_fraction": finite_number(e.drop_fraction, "drop_fraction"),
                "trigger": str(e.trigger),
                "kind": str(e.kind),
                "detector": present(detector),
                "joint": integer_or_none(self.joint, "joint"),
                "train_drops": integer(self.train_drops, "train_drops"),
            }
        )

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> SlipMessage:
        """Decode a `/rig/slip` payload back into the `SlipEvent` the detector emitted."""
        event = SlipEvent(
            onset_time_ns=time_ns_from_payload(payload, "onset_time_ns"),
            detection_time_ns=time_ns_from_payload(payload, "detection_time_ns"),
            peak_time_ns=time_ns_from_payload(payload, "peak_time_ns"),
            peak_force_n=float(payload["peak_force_n"]),
            force_after_n=float(payload["force_after_n"]),
            drop_fraction=float(payload["drop_fraction"]),
            trigger=str(payload["trigger"]),
            kind=SlipEventKind(payload["kind"]),
        )
        detector = payload.get("detector") or {}
        return cls(
            trial_id=integer(payload["trial_id"], "trial_id"),
            event=event,
            detector={str(k): number_or_none(v, k) for k, v in detector.items()},
            joint=integer_or_none(payload.get("joint"), "joint"),
            train_drops=integer(payload.get("train_drops") or 0, "train_drops"),
        )


@dataclass(frozen=True, slots=True)
class TrialResult:
    """One finished trial: what was planned, what was measured and predicted, and how it ended.

    The same record is the journal entry, a `rig run --json` trial, the `/rig/trial/result`
    payload and what replay reads back.
    """

    trial_id: int
    kind: TrialKind
    repeat: int
    joint: int | None  # joint under test (joint estimation)
    distance_m: float | None  # load distance (joint estimation)
    configuration_index: int | None  # configuration of the plan (link validation)
    joint_angles_rad: tuple[float, ...] | None  # measured (else commanded) configuration
    start_time_ns: int
    end_time_ns: int
    outcome: TrialOutcome
    peak_force_n: float | None  # the slip load (slip), or the highest tension seen (no slip)
    slip_mass_kg: float | None  # peak_force_n / g
    predicted_force_n: float | None  # from the estimates before this trial
    predicted_mass_kg: float | None
    percentage_error: float | None  # (predicted − measured) / measured · 100, link-validation slips
    slipped_joint: int | None  # 1-based, when the configuration source reports it
    lever_arms_m: tuple[float, ...] | None  # of the line about each joint (link validation)
    tare_n: float  # load-cell offset removed before the ramp
    reason: str | None = None  # why an aborted trial stopped (None otherwise)

    @property
    def slipped(self) -> bool:
        """Whether the trial ended in a slip of the joint under test (`SLIP_LIKE`): fit material."""
        return self.outcome in SLIP_LIKE

    def to_json(self) -> dict[str, Any]:
        """The journal entry and `rig run --json` trial: every field, plain JSON values."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, StrEnum):
                value = value.value
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> TrialResult:
        """Read a journal entry back; KeyError or ValueError name a missing or bad field."""
        return cls(
            trial_id=integer(data["trial_id"], "trial_id"),
            kind=TrialKind(data["kind"]),
            repeat=integer(data.get("repeat", 0), "repeat"),
            joint=integer_or_none(data.get("joint"), "joint"),
            distance_m=number_or_none(data.get("distance_m"), "distance_m"),
            configuration_index=integer_or_none(data.get("configuration_index"), "configuration_index"),
            joint_angles_rad=_tuple_or_none(data.get("joint_angles_rad")),
            start_time_ns=integer(data["start_time_ns"], "start_time_ns"),
            end_time_ns=integer(data["end_time_ns"], "end_time_ns"),
            outcome=TrialOutcome(data["outcome"]),
            peak_force_n=number_or_none(data.get("peak_force_n"), "peak_force_n"),
            slip_mass_kg=number_or_none(data.get("slip_mass_kg"), "slip_mass_kg"),
            predicted_force_n=number_or_none(data.get("predicted_force_n"), "predicted_force_n"),
            predicted_mass_kg=number_or_none(data.get("predicted_mass_kg"), "predicted_mass_kg"),
            percentage_error=number_or_none(data.get("percentage_error"), "percentage_error"),
            slipped_joint=integer_or_none(data.get("slipped_joint"), "slipped_joint"),
            lever_arms_m=_tuple_or_none(data.get("lever_arms_m")),
            tare_n=float(data.get("tare_n") or 0.0),
            reason=None if data.get("reason") is None else str(data["reason"]),
        )

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/trial/result` payload: every field that has a value, times as stamps.

        None and non-finite numbers are left out.
        """
        return present(
            {
                "trial_id": integer(self.trial_id, "trial_id"),
                "kind": TrialKind(self.kind).value,
                "repeat": integer(self.repeat, "repeat"),
                "joint": integer_or_none(self.joint, "joint"),
                "distance_m": number_or_none(self.distance_m, "distance_m"),
                "configuration_index": integer_or_none(self.configuration_index, "configuration_index"),
                "joint_angles_rad": _numbers_or_none(self.joint_angles_rad, "joint_angles_rad"),
                "start": stamp(self.start_time_ns),
                "end": stamp(self.end_time_ns),
                "outcome": TrialOutcome(self.outcome).value,
                "peak_force_n": number_or_none(self.peak_force_n, "peak_force_n"),
                "slip_mass_kg": number_or_none(self.slip_mass_kg, "slip_mass_kg"),
                "predicted_force_n": number_or_none(self.predicted_force_n, "predicted_force_n"),
                "predicted_mass_kg": number_or_none(self.predicted_mass_kg, "predicted_mass_kg"),
                "percentage_error": number_or_none(self.percentage_error, "percentage_error"),
                "slipped_joint": integer_or_none(self.slipped_joint, "slipped_joint"),
                "lever_arms_m": _numbers_or_none(self.lever_arms_m, "lever_arms_m"),
                "tare_n": finite_number(self.tare_n, "tare_n"),
                "reason": None if self.reason is None else str(self.reason),
            }
        )

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> TrialResult:
        """Decode a `/rig/trial/result` payload (times from the `start` and `end` stamps)."""
        data = dict(payload)
        for time_field in ("start_time_ns", "end_time_ns"):
            data[time_field] = time_ns_from_payload(payload, time_field)
        return cls.from_json(data)


@dataclass(frozen=True, slots=True)
class JointCapacity:
    """One joint's estimated capacity with its bounds [N·m] (None where not estimated)."""

    joint: int  # 1-based, from the base
    capacity_nm: float | None
    ci_lo_nm: float | None
    ci_hi_nm: float | None

    def to_json(self) -> dict[str, Any]:
        """As in `/rig/estimate` and `rig run --json`."""
        return {
            "joint": integer(self.joint, "joint"),
            "capacity_nm": number_or_none(self.capacity_nm, "capacity_nm"),
            "ci_lo_nm": number_or_none(self.ci_lo_nm, "ci_lo_nm"),
            "ci_hi_nm": number_or_none(self.ci_hi_nm, "ci_hi_nm"),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> JointCapacity:
        """Decode one joint of `/rig/estimate`."""
        return cls(
            joint=integer(data["joint"], "joint"),
            capacity_nm=number_or_none(data.get("capacity_nm"), "capacity_nm"),
            ci_lo_nm=number_or_none(data.get("ci_lo_nm"), "ci_lo_nm"),
            ci_hi_nm=number_or_none(data.get("ci_hi_nm"), "ci_hi_nm"),
        )


@dataclass(frozen=True, slots=True)
class Estimate:
    """The run's estimate after a trial: the joint-estimation fit (None before 2 slips) and joints.

    `fit` is the protocol's estimator's (`estimator`); the paper's fit is carried beside it in the
    `paper_*` fields (equal to `fit`'s when the estimator is `paper`).
    """

    trial_id: int
    fit: FitSummary | None
    joints: tuple[JointCapacity, ...] = ()
    estimator: str = "paper"
    scatter_model: str | None = None  # what the estimator assumed or the data supported
    n_censored: int = 0  # no-slip trials in the fit as lower bounds
    scatter_a_kg: float | None = None  # sd(m)² = a² + (b·m)²
    scatter_b: float | None = None
    p_additive: float | None = None  # the diagnostic's p-values (auto only)
    p_multiplicative: float | None = None
    paper_n: int | None = None
    paper_k: float | None = None
    paper_k_ci: tuple[float, float] | None = None
    paper_se: float | None = None
    paper_rmse: float | None = None
    paper_capacity_nm: float | None = None
    paper_capacity_ci_nm: tuple[float, float] | None = None

    def text(self) -> str:
        """One line for people: k and the capacity with its bounds, and the paper's beside them."""
        s = self.fit
        if s is None:
            return "estimate: needs 2 slips"
        lo, hi = nonnegative_bounds(s.capacity_ci_nm)  # a capacity is >= 0 (model.fit)
        line = f"k={s.k:.4f} kg·m  capacity={s.capacity_nm:.3f} N·m [{lo:.3f}, {hi:.3f}] (n={s.n}"
        line += f", {self.n_censored} censored)" if self.n_censored else ")"
        if self.estimator == "paper" or self.paper_capacity_ci_nm is None or self.paper_capacity_nm is None:
            return line
        plo, phi = nonnegative_bounds(self.paper_capacity_ci_nm)
        scatter = f" {self.scatter_model}" if self.scatter_model else ""
        paper = f"paper: {self.paper_capacity_nm:.3f} [{plo:.3f}, {phi:.3f}]"
        return f"{self.estimator}{scatter}: {line}  {paper}"

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/estimate` payload: the `rig fit --json` keys (absent before a fit; n = 0) and joints.

        A pair with an undefined bound is left out whole. `capacity_bounded` says whether the
        capacity and both its bounds are there: a viewer plotting them against `trial_id` filters
        on it, so that its series pair up message by message.
        """
        payload: dict[str, Any] = {"trial_id": integer(self.trial_id, "trial_id")}
        summary = self.fit.as_json() if self.fit is not None else {}
        for f in fields(FitSummary):
            payload[f.name] = _fit_value(f.name, summary.get(f.name))
        if payload["n"] is None:
            payload["n"] = 0
        payload["joints"] = [present(j.to_json()) for j in self.joints]
        payload["estimator"] = str(self.estimator)
        payload["scatter_model"] = self.scatter_model
        payload["n_censored"] = integer(self.n_censored, "n_censored")
        for name in _ESTIMATE_NUMBERS:
            payload[name] = number_or_none(getattr(self, name), name)
        payload["paper_n"] = None if self.paper_n is None else integer(self.paper_n, "paper_n")
        for name in ("paper_k_ci", "paper_capacity_ci_nm"):
            payload[name] = _pair_or_none(getattr(self, name), name)
        payload["capacity_bounded"] = (
            payload["capacity_nm"] is not None and payload["capacity_ci_nm"] is not None
        )
        return present(payload)

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> Estimate:
        """Decode a `/rig/estimate` payload (no fit when `n` is 0 or `k` is missing).

        Fit values that are absent (undefined) become NaN.
        """
        fit = None
        if payload.get("n") and payload.get("k") is not None:
            fit = FitSummary.from_json(
                {
                    name: payload.get(name, _MISSING_PAIR if name in _FIT_PAIR_KEYS else None)
                    for name in SUMMARY_KEYS
                }
            )
        joints = tuple(JointCapacity.from_json(j) for j in payload.get("joints") or ())
        numbers = {name: _optional_float(payload.get(name)) for name in _ESTIMATE_NUMBERS}
        scatter = payload.get("scatter_model")
        paper_n = payload.get("paper_n")
        return cls(
            trial_id=integer(payload["trial_id"], "trial_id"),
            fit=fit,
            joints=joints,
            estimator=str(payload["estimator"]),
            scatter_model=None if scatter is None else str(scatter),
            n_censored=integer(payload.get("n_censored") or 0, "n_censored"),
            paper_n=None if paper_n is None else integer(paper_n, "paper_n"),
            paper_k_ci=_optional_pair(payload.get("paper_k_ci")),
            paper_capacity_ci_nm=_optional_pair(payload.get("paper_capacity_ci_nm")),
            **numbers,
        )


_ESTIMATE_NUMBERS = (
    "scatter_a_kg",
    "scatter_b",
    "p_additive",
    "p_multiplicative",
    "paper_k",
    "paper_se",
    "paper_rmse",
    "paper_capacity_nm",
)


def _optional_float(value: Any) -> float | None:
    return None if value is None else float(value)


_FIT_PAIR_KEYS = frozenset(f.name for f in fields(FitSummary) if f.name.endswith("_ci") or "_ci_" in f.name)
_MISSING_PAIR = (None, None)


def _pair_or_none(pair: Sequence[Any] | None, name: str) -> list[float] | None:
    """A pair of finite bounds as a list; None (left out) if either bound is missing or not finite."""
    if pair is None:
        return None
    bounds = [number_or_none(b, name) for b in pair]
    return None if None in bounds else bounds  # type: ignore[return-value]


def _optional_pair(value: Any) -> tuple[float, float] | None:
    if value is None:
        return None
    lo, hi = value
    return (math.nan if lo is None else float(lo), math.nan if hi is None else float(hi))


_FIT_INTEGER_KEYS = frozenset({"n", "dfe"})


def _fit_value(key: str, value: Any) -> Any:
    if value is None:
        return None
    if key in _FIT_INTEGER_KEYS:
        return integer(value, key)
    if key == "constant":
        return str(value)
    if isinstance(value, list | tuple):
        return _pair_or_none(value, key)
    return number_or_none(value, key)


@dataclass(frozen=True, slots=True)
class LogMessage:
    """A human-readable event (`/rig/log`, Foxglove's well-known `foxglove.Log`)."""

    time_ns: int
    level: LogLevel
    message: str
    name: str = "rig"
    file: str = ""
    line: int = 0

    def to_payload(self) -> dict[str, Any]:
        """The `foxglove.Log` payload."""
        return {
            "timestamp": stamp(self.time_ns),
            "level": int(LogLevel(self.level)),
            "message": str(self.message),
            "name": str(self.name),
            "file": str(self.file),
            "line": integer(self.line, "line"),
        }


__all__ = [
    "SLIP_LIKE",
    "ControlTickStats",
    "Estimate",
    "JointCapacity",
    "LogLevel",
    "LogMessage",
    "ServoCommand",
    "ServoCommandName",
    "SlipEvent",
    "SlipMessage",
    "TrialKind",
    "TrialOutcome",
    "TrialPhase",
    "TrialResult",
    "TrialState",
    "stamp",
    "time_ns_from_payload",
]


@dataclass(frozen=True, slots=True)
class TrialWireStats:
    """What the device wires delivered and lost during one trial (`/rig/trial/links`).

    The topic and its schema name (`rig.TrialLinkStats`) keep their names: they are the log
    contract (docs/formats.md); "wire" is the code's word for a device connection.

    `bus`: the servo bus's exchanges (retries, timeouts, corrupt replies, reboots, Bus Watchdog
    trips, ...); `loadcell`: the load cell's serial lines; `control`: the control loop's ticks and
    how many started late. A device that keeps no counts (the object-level
    simulation) leaves its part out of the payload: absent, never null.
    """

    trial_id: int
    bus: BusStats | None = None
    loadcell: LoadCellLineStats | None = None
    control: ControlTickStats | None = None

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/trial/links` payload."""
        out: dict[str, Any] = {"trial_id": integer(self.trial_id, "trial_id")}
        parts: tuple[tuple[str, Any], ...] = (
            ("bus", self.bus),
            ("loadcell", self.loadcell),
            ("control", self.control),
        )
        for name, counts in parts:
            if counts is not None:
                out[name] = {
                    f.name: integer(getattr(counts, f.name), f"{name}.{f.name}") for f in fields(counts)
                }
        return out

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> TrialWireStats:
        """Decode a `/rig/trial/links` payload (a part read back from a table as all-missing is absent)."""

        def counts(name: str, kind: type[Any]) -> Any:
            part = payload.get(name)
            if not isinstance(part, Mapping) or all(v is None for v in part.values()):
                return None
            return kind(**{f.name: integer(part[f.name], f"{name}.{f.name}") for f in fields(kind)})

        return cls(
            trial_id=integer(payload["trial_id"], "trial_id"),
            bus=counts("bus", BusStats),
            loadcell=counts("loadcell", LoadCellLineStats),
            control=counts("control", ControlTickStats),
        )


@dataclass(frozen=True, slots=True)
class ConfigurationMeasurement:
    """One measurement of the link's configuration (`/rig/configuration/measured`), beside the commanded one.

    Angles in rad, joint 1 (base) first; `uncertainty_rad` is each angle's standard deviation where
    the source knows it. `stage`: after bending (`attempt` 0, then n after the n-th correction) or
    after a slip (`slipped_joint`: the joint that moved, when the source or the comparison with the
    measurement before could tell). Absent values are absent fields, never null.
    """

    trial_id: int
    source: ConfigurationSourceKind
    stage: MeasurementStage
    measured_time_ns: int
    attempt: int = 0
    configuration_index: int | None = None
    joint_angles_rad: tuple[float, ...] | None = None
    uncertainty_rad: tuple[float, ...] | None = None
    commanded_angles_rad: tuple[float, ...] | None = None
    slipped_joint: int | None = None

    def to_payload(self) -> dict[str, Any]:
        """The `/rig/configuration/measured` payload."""
        return present(
            {
                "trial_id": integer(self.trial_id, "trial_id"),
                "source": ConfigurationSourceKind(self.source).value,
                "stage": MeasurementStage(self.stage).value,
                "measured": stamp(self.measured_time_ns),
                "attempt": integer(self.attempt, "attempt"),
                "configuration_index": integer_or_none(self.configuration_index, "configuration_index"),
                "joint_angles_rad": _numbers_or_none(self.joint_angles_rad, "joint_angles_rad"),
                "uncertainty_rad": _numbers_or_none(self.uncertainty_rad, "uncertainty_rad"),
                "commanded_angles_rad": _numbers_or_none(self.commanded_angles_rad, "commanded_angles_rad"),
                "slipped_joint": integer_or_none(self.slipped_joint, "slipped_joint"),
            }
        )

    @classmethod
    def from_payload(cls, payload: Mapping[str, Any]) -> ConfigurationMeasurement:
        """Decode a `/rig/configuration/measured` payload."""
        return cls(
            trial_id=integer(payload["trial_id"], "trial_id"),
            source=ConfigurationSourceKind(payload["source"]),
            stage=MeasurementStage(payload["stage"]),
            measured_time_ns=time_ns_from_payload(payload, "measured_time_ns"),
            attempt=integer(payload.get("attempt") or 0, "attempt"),
            configuration_index=integer_or_none(payload.get("configuration_index"), "configuration_index"),
            joint_angles_rad=_tuple_or_none(payload.get("joint_angles_rad")),
            uncertainty_rad=_tuple_or_none(payload.get("uncertainty_rad")),
            commanded_angles_rad=_tuple_or_none(payload.get("commanded_angles_rad")),
            slipped_joint=integer_or_none(payload.get("slipped_joint"), "slipped_joint"),
        )


@dataclass(frozen=True, slots=True)
class ControlTickStats:
    """The control loop's ticks during one trial (`control` of `/rig/trial/links`).

    A tick is late when it starts after its scheduled time (the previous tick's work, or a host
    pause, overran the period); its lateness is how much after.
    """

    ticks: int = 0
    late_ticks: int = 0
    max_lateness_us: int = 0
    total_lateness_us: int = 0
