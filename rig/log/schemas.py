"""The MCAP topic contract: JSON Schemas of every rig topic, payload builders and a cheap checker.

Every topic is JSON-encoded with a `jsonschema` schema whose top level is an object (Foxglove needs
that). High-rate messages are flat; a missing number is `null` (`["number", "null"]`), never NaN.
Integers stay below 2**53 so that JavaScript readers see them exactly, except the epoch-nanosecond
fields named `*_time_ns` (kept exact for Python replay): each has a `{sec, nsec}` twin for
JavaScript and Foxglove.

The builders (`loadcell_sample`, `servo_state`, ...) are how the runner makes payloads: they
coerce numpy scalars to plain Python numbers, map non-finite values of nullable numbers to `null`
and reject them elsewhere, so a payload they return always satisfies its schema. `check_payload`
validates any payload against its schema (types, required keys, enums, ranges); `RunLogger` calls
it per message only in strict mode (tests), since the builders already guarantee the contract.
"""

from __future__ import annotations

import json
import math
import operator
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Any

from model.fit import SUMMARY_KEYS
from rig.hw.seams import LoadCellSample, ServoState

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
MAX_SAFE_INT = 2**53 - 1  # largest integer a JavaScript double holds exactly
NS_PER_S = 1_000_000_000

LOADCELL = "/rig/loadcell"
SERVO_STATE = "/rig/servo/state"
SERVO_COMMAND = "/rig/servo/command"
TRIAL_STATE = "/rig/trial/state"
SLIP = "/rig/slip"
TRIAL_RESULT = "/rig/trial/result"
ESTIMATE = "/rig/estimate"
LOG = "/rig/log"


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


class LogLevel(IntEnum):
    """`foxglove.Log` levels."""

    UNKNOWN = 0
    DEBUG = 1
    INFO = 2
    WARNING = 3
    ERROR = 4
    FATAL = 5


SERVO_COMMANDS = (
    "goal_position",
    "goal_current",
    "goal_velocity",
    "profile_velocity",
    "profile_acceleration",
    "torque",
    "mode",
    "reboot",
)
TRIAL_KINDS = ("joint_estimation", "link_validation")
TRIAL_OUTCOMES = ("slip", "no_slip", "aborted", "fault")
FIT_KEYS = SUMMARY_KEYS  # the `rig fit --json` keys, defined with the fit itself
_FIT_INTEGER_KEYS = frozenset({"n", "dfe"})
_FIT_INTERVAL_KEYS = frozenset({"k_ci", "mu_delta0_ci_pa", "capacity_ci_nm"})

# ---------------------------------------------------------------------------------------------
# JSON Schema pieces

_NUMBER = {"type": "number"}
_NUMBER_OR_NULL = {"type": ["number", "null"]}
_INTEGER = {"type": "integer"}
_INTEGER_OR_NULL = {"type": ["integer", "null"]}
_STRING = {"type": "string"}
_STRING_OR_NULL = {"type": ["string", "null"]}
_TIME_NS = {
    "type": "integer",
    "minimum": 0,
    "description": "epoch ns (exceeds 2^53: use the {sec,nsec} twin)",
}
_TIMESTAMP = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}
_INTERVAL_OR_NULL = {
    "type": ["array", "null"],
    "items": _NUMBER_OR_NULL,
    "minItems": 2,
    "maxItems": 2,
    "description": "[lower, upper]",
}


def _rig_object(title: str, description: str, properties: dict[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }


_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    LOADCELL: (
        "rig.LoadCellSample",
        _rig_object(
            "rig.LoadCellSample",
            "One load-cell sample; log_time is its host receive time.",
            {
                "seq": {**_INTEGER_OR_NULL, "description": "device sequence counter"},
                "raw": {**_INTEGER, "description": "ADC counts as sent by the device"},
                "force_n": {**_NUMBER, "description": "calibrated line tension, N"},
                "device_time_us": {**_INTEGER_OR_NULL, "description": "device clock, us"},
            },
        ),
    ),
    SERVO_STATE: (
        "rig.ServoState",
        _rig_object(
            "rig.ServoState",
            "One servo's state from one bus read.",
            {
                "servo_id": _INTEGER,
                "role": _STRING,
                "position_rad": _NUMBER,
                "velocity_rad_s": _NUMBER,
                "current_a": _NUMBER,
                "hardware_error": {**_INTEGER, "minimum": 0, "description": "Hardware Error Status bits"},
                "moving": {"type": "boolean"},
            },
        ),
    ),
    SERVO_COMMAND: (
        "rig.ServoCommand",
        _rig_object(
            "rig.ServoCommand",
            "A command sent to a servo (log_time = when it was sent).",
            {
                "servo_id": _INTEGER,
                "role": _STRING,
                "command": {"type": "string", "enum": list(SERVO_COMMANDS)},
                "value": {**_NUMBER_OR_NULL, "description": "setpoint in `unit`; null for reboot"},
                "unit": {**_STRING, "description": "e.g. rad, A, rad/s, bool, mode; empty if none"},
            },
        ),
    ),
    TRIAL_STATE: (
        "rig.TrialState",
        _rig_object(
            "rig.TrialState",
            "A phase change of the runner.",
            {
                "trial_id": {**_INTEGER_OR_NULL, "description": "null outside trials"},
                "phase": {"type": "string", "enum": [p.value for p in TrialPhase]},
                "step": _STRING_OR_NULL,
            },
        ),
    ),
    SLIP: (
        "rig.SlipEvent",
        _rig_object(
            "rig.SlipEvent",
            "A slip detected in the load-cell signal.",
            {
                "trial_id": _INTEGER,
                "onset_time_ns": _TIME_NS,
                "detection_time_ns": _TIME_NS,
                "peak_time_ns": _TIME_NS,
                "onset": _TIMESTAMP,
                "detection": _TIMESTAMP,
                "peak_force_n": _NUMBER,
                "force_after_n": _NUMBER,
                "drop_fraction": _NUMBER,
                "detector": {
                    "type": "object",
                    "description": "detector parameters by name",
                    "additionalProperties": _NUMBER_OR_NULL,
                },
                "trigger": {**_STRING, "description": "what fired the detector"},
                "joint": {**_INTEGER_OR_NULL, "description": "1-based joint that slipped, if known"},
            },
        ),
    ),
    TRIAL_RESULT: (
        "rig.TrialResult",
        _rig_object(
            "rig.TrialResult",
            "The result of one trial.",
            {
                "trial_id": _INTEGER,
                "kind": {"type": "string", "enum": list(TRIAL_KINDS)},
                "distance_m": _NUMBER_OR_NULL,
                "configuration": {
                    "type": ["object", "null"],
                    "properties": {
                        "joint_angles_rad": {"type": "array", "items": _NUMBER},
                        "transforms": {
                            "type": "array",
                            "description": "(J, 4, 4) pose of {i} in {i-1}, row-major",
                            "items": {"type": "array", "items": {"type": "array", "items": _NUMBER}},
                        },
                    },
                    "additionalProperties": False,
                },
                "start": _TIMESTAMP,
                "end": _TIMESTAMP,
                "start_time_ns": _TIME_NS,
                "end_time_ns": _TIME_NS,
                "peak_force_n": _NUMBER_OR_NULL,
                "slip_mass_kg": _NUMBER_OR_NULL,
                "predicted_mass_kg": _NUMBER_OR_NULL,
                "slipped_joint": _INTEGER_OR_NULL,
                "outcome": {"type": "string", "enum": list(TRIAL_OUTCOMES)},
                "repeat": {**_INTEGER, "minimum": 0},
                "lever_arms_m": {"type": ["array", "null"], "items": _NUMBER},
            },
        ),
    ),
    ESTIMATE: (
        "rig.Estimate",
        _rig_object(
            "rig.Estimate",
            "The online estimate after a trial (keys as `rig fit --json`; null where undefined).",
            {
                "trial_id": _INTEGER,
                "n": {**_INTEGER, "minimum": 0},
                "k": _NUMBER_OR_NULL,
                "k_ci": _INTERVAL_OR_NULL,
                "sse": _NUMBER_OR_NULL,
                "sst": _NUMBER_OR_NULL,
                "r2": _NUMBER_OR_NULL,
                "rmse": _NUMBER_OR_NULL,
                "dfe": _INTEGER_OR_NULL,
                "se": _NUMBER_OR_NULL,
                "level": _NUMBER_OR_NULL,
                "constant": _STRING_OR_NULL,
                "c": _NUMBER_OR_NULL,
                "radius_m": _NUMBER_OR_NULL,
                "mu_delta0_pa": _NUMBER_OR_NULL,
                "mu_delta0_ci_pa": _INTERVAL_OR_NULL,
                "capacity_nm": _NUMBER_OR_NULL,
                "capacity_ci_nm": _INTERVAL_OR_NULL,
                "joints": {
                    "type": "array",
                    "items": {
                        "type": "object",
                        "properties": {
                            "joint": _INTEGER,
                            "capacity_nm": _NUMBER_OR_NULL,
                            "ci_lo_nm": _NUMBER_OR_NULL,
                            "ci_hi_nm": _NUMBER_OR_NULL,
                        },
                        "required": ["joint", "capacity_nm", "ci_lo_nm", "ci_hi_nm"],
                        "additionalProperties": False,
                    },
                },
            },
        ),
    ),
    # The exact well-known schema (name and fields) that Foxglove's Log panel recognizes.
    LOG: (
        "foxglove.Log",
        {
            "title": "foxglove.Log",
            "description": "A log message",
            "type": "object",
            "properties": {
                "timestamp": {**_TIMESTAMP, "description": "Timestamp of log message"},
                "level": {
                    "title": "foxglove.LogLevel",
                    "description": "Log level",
                    "oneOf": [{"title": lv.name, "const": int(lv)} for lv in LogLevel],
                },
                "message": {"type": "string", "description": "Log message"},
                "name": {"type": "string", "description": "Process or node name"},
                "file": {"type": "string", "description": "Filename"},
                "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
            },
            "required": ["timestamp", "level", "message", "name", "file", "line"],
        },
    ),
}


@dataclass(frozen=True)
class TopicSpec:
    """One topic of the contract: its name, schema name and JSON Schema."""

    topic: str
    schema_name: str
    schema: Mapping[str, Any]

    @property
    def schema_bytes(self) -> bytes:
        """The schema as stored in the MCAP Schema record."""
        return json.dumps(self.schema, separators=(",", ":")).encode()


TOPICS: dict[str, TopicSpec] = {
    topic: TopicSpec(topic, name, schema) for topic, (name, schema) in _SCHEMAS.items()
}


def schema_for(topic: str) -> TopicSpec:
    """The spec of a rig topic; `KeyError` naming the known topics otherwise."""
    try:
        return TOPICS[topic]
    except KeyError:
        raise KeyError(f"unknown topic {topic!r}; known: {', '.join(TOPICS)}") from None


# ---------------------------------------------------------------------------------------------
# Checking payloads against the schemas (the subset of JSON Schema used above)


def json_types(schema: Mapping[str, Any]) -> tuple[str, ...]:
    """The JSON types a schema fragment allows (empty if it does not say)."""
    t = schema.get("type")
    if t is None:
        return ()
    return (t,) if isinstance(t, str) else tuple(t)


def _check(schema: Mapping[str, Any], value: Any, path: str) -> str | None:
    """First violation of `schema` by `value` (a message naming `path`), or None."""
    types = json_types(schema)
    if value is None:
        return None if "null" in types else f"{path}: null not allowed"
    if "oneOf" in schema:
        consts = [alt["const"] for alt in schema["oneOf"] if "const" in alt]
        if isinstance(value, bool) or not isinstance(value, int) or value not in consts:
            return f"{path}: {value!r} not one of {consts}"
        return None
    if "enum" in schema and value not in schema["enum"]:
        return f"{path}: {value!r} not one of {schema['enum']}"
    kind = type(value)
    if isinstance(value, bool):
        if "boolean" not in types:
            return f"{path}: got a bool, expected {'/'.join(types)}"
        return None
    if isinstance(value, int):  # IntEnum serializes as its value
        if "integer" not in types and "number" not in types:
            return f"{path}: got an integer, expected {'/'.join(types)}"
        limit = 2**63 - 1 if path.endswith("_time_ns") else MAX_SAFE_INT
        if abs(value) > limit:
            return f"{path}: {value} exceeds {limit} (JavaScript readers lose precision)"
        return _check_range(schema, value, path)
    if isinstance(value, float):  # includes numpy.float64
        if "number" not in types:
            return f"{path}: got a float, expected {'/'.join(types)}"
        if not math.isfinite(value):
            return f"{path}: {value} is not finite (use null)"
        return _check_range(schema, value, path)
    if isinstance(value, str):  # includes StrEnum members
        return None if "string" in types else f"{path}: got a string, expected {'/'.join(types)}"
    if isinstance(value, Mapping):
        if "object" not in types:
            return f"{path}: got an object, expected {'/'.join(types)}"
        return _check_object(schema, value, path)
    if isinstance(value, list | tuple):
        if "array" not in types:
            return f"{path}: got an array, expected {'/'.join(types)}"
        if "minItems" in schema and len(value) < schema["minItems"]:
            return f"{path}: {len(value)} items, at least {schema['minItems']} required"
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            return f"{path}: {len(value)} items, at most {schema['maxItems']} allowed"
        items = schema.get("items")
        if items is not None:
            for i, item in enumerate(value):
                problem = _check(items, item, f"{path}[{i}]")
                if problem:
                    return problem
        return None
    return f"{path}: {kind.__name__} is not a JSON type (convert numpy scalars with float()/int())"


def _check_range(schema: Mapping[str, Any], value: float, path: str) -> str | None:
    if "minimum" in schema and value < schema["minimum"]:
        return f"{path}: {value} below the minimum {schema['minimum']}"
    if "maximum" in schema and value > schema["maximum"]:
        return f"{path}: {value} above the maximum {schema['maximum']}"
    return None


def _check_object(schema: Mapping[str, Any], value: Mapping[str, Any], path: str) -> str | None:
    properties = schema.get("properties", {})
    for key in schema.get("required", ()):
        if key not in value:
            return f"{path}: missing required key {key!r}"
    extra = schema.get("additionalProperties", True)
    for key, item in value.items():
        if not isinstance(key, str):
            return f"{path}: key {key!r} is not a string"
        sub = properties.get(key)
        if sub is None:
            if extra is False:
                return f"{path}: unexpected key {key!r}; allowed: {', '.join(properties)}"
            if extra is True:
                continue
            sub = extra
        problem = _check(sub, item, f"{path}.{key}" if path else key)
        if problem:
            return problem
    return None


def check_payload(topic: str, payload: Mapping[str, Any]) -> None:
    """Raise `ValueError` naming the topic and field if `payload` violates the topic's schema."""
    spec = schema_for(topic)
    if not isinstance(payload, Mapping):
        raise ValueError(f"{topic}: payload must be a dict, got {type(payload).__name__}")
    problem = _check_object(spec.schema, payload, "")
    if problem:
        raise ValueError(f"{topic} ({spec.schema_name}): {problem}")


# ---------------------------------------------------------------------------------------------
# Builders


def stamp(time_ns: int) -> dict[str, int]:
    """Epoch nanoseconds as a `{sec, nsec}` timestamp (foxglove.Timestamp)."""
    t = _int(time_ns, "time_ns")
    if t < 0:
        raise ValueError(f"time_ns: {t} is before the epoch")
    sec, nsec = divmod(t, NS_PER_S)
    return {"sec": sec, "nsec": nsec}


def _num(value: Any, field: str) -> float:
    if value is None or isinstance(value, bool):
        raise ValueError(f"{field}: {value!r} is not a number")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{field}: {x} is not a finite number")
    return x


def _num_or_none(value: Any, field: str) -> float | None:
    """A nullable number: None and non-finite values become null."""
    if value is None:
        return None
    if isinstance(value, bool):
        raise ValueError(f"{field}: {value!r} is not a number")
    x = float(value)
    return x if math.isfinite(x) else None


def _int(value: Any, field: str) -> int:
    if value is None or isinstance(value, bool):
        raise ValueError(f"{field}: {value!r} is not an integer")
    try:
        return operator.index(value)
    except TypeError:
        raise ValueError(f"{field}: {value!r} is not an integer") from None


def _int_or_none(value: Any, field: str) -> int | None:
    return None if value is None else _int(value, field)


def _choice(value: Any, field: str, allowed: Iterable[str]) -> str:
    allowed = tuple(allowed)
    text = str(value)
    if text not in allowed:
        raise ValueError(f"{field}: {value!r} not allowed; allowed: {', '.join(allowed)}")
    return text


def loadcell_sample(
    *, raw: int, force_n: float, seq: int | None = None, device_time_us: int | None = None
) -> dict[str, Any]:
    """A `/rig/loadcell` payload."""
    if (
        type(raw) is int
        and type(force_n) is float
        and math.isfinite(force_n)
        and (seq is None or type(seq) is int)
        and (device_time_us is None or type(device_time_us) is int)
    ):
        # The common case (1 kHz from the driver): already the exact types the checks below produce.
        return {"seq": seq, "raw": raw, "force_n": force_n, "device_time_us": device_time_us}
    return {
        "seq": _int_or_none(seq, "seq"),
        "raw": _int(raw, "raw"),
        "force_n": _num(force_n, "force_n"),
        "device_time_us": _int_or_none(device_time_us, "device_time_us"),
    }


# Topics whose payload may also be given as a row: a tuple of the values in this order (no dict to
# build and pickle per message at 1 kHz). `RunLogger.log_many` accepts rows; the file holds the
# same JSON object either way.
ROW_FIELDS: dict[str, tuple[str, ...]] = {LOADCELL: ("seq", "raw", "force_n", "device_time_us")}


def loadcell_payload(sample: LoadCellSample) -> dict[str, Any]:
    """A `/rig/loadcell` payload from the hardware seam's value type (log it at `sample.time_ns`)."""
    return loadcell_sample(
        raw=sample.raw, force_n=sample.force_n, seq=sample.seq, device_time_us=sample.device_time_us
    )


def servo_state(
    *,
    servo_id: int,
    role: str,
    position_rad: float,
    velocity_rad_s: float,
    current_a: float,
    hardware_error: int,
    moving: bool,
) -> dict[str, Any]:
    """A `/rig/servo/state` payload."""
    return {
        "servo_id": _int(servo_id, "servo_id"),
        "role": str(role),
        "position_rad": _num(position_rad, "position_rad"),
        "velocity_rad_s": _num(velocity_rad_s, "velocity_rad_s"),
        "current_a": _num(current_a, "current_a"),
        "hardware_error": _int(hardware_error, "hardware_error"),
        "moving": bool(moving),
    }


def servo_state_payload(state: ServoState, role: str) -> dict[str, Any]:
    """A `/rig/servo/state` payload from the hardware seam's value type (log it at `state.time_ns`)."""
    return servo_state(
        servo_id=state.servo_id,
        role=role,
        position_rad=state.position_rad,
        velocity_rad_s=state.velocity_rad_s,
        current_a=state.current_a,
        hardware_error=state.hardware_error,
        moving=state.moving,
    )


def servo_command(
    *, servo_id: int, role: str, command: str, value: float | None, unit: str
) -> dict[str, Any]:
    """A `/rig/servo/command` payload; `command` is one of `SERVO_COMMANDS`."""
    return {
        "servo_id": _int(servo_id, "servo_id"),
        "role": str(role),
        "command": _choice(command, "command", SERVO_COMMANDS),
        "value": _num_or_none(value, "value"),
        "unit": str(unit),
    }


def trial_state(*, trial_id: int | None, phase: str, step: str | None = None) -> dict[str, Any]:
    """A `/rig/trial/state` payload; `phase` is a `TrialPhase` (or its string value)."""
    return {
        "trial_id": _int_or_none(trial_id, "trial_id"),
        "phase": _choice(phase, "phase", (p.value for p in TrialPhase)),
        "step": None if step is None else str(step),
    }


def slip_event(
    *,
    trial_id: int,
    onset_time_ns: int,
    detection_time_ns: int,
    peak_time_ns: int,
    peak_force_n: float,
    force_after_n: float,
    drop_fraction: float,
    detector: Mapping[str, float | None],
    trigger: str,
    joint: int | None = None,
) -> dict[str, Any]:
    """A `/rig/slip` payload; `detector` maps parameter names to numbers."""
    onset_ns = _int(onset_time_ns, "onset_time_ns")
    detection_ns = _int(detection_time_ns, "detection_time_ns")
    return {
        "trial_id": _int(trial_id, "trial_id"),
        "onset_time_ns": onset_ns,
        "detection_time_ns": detection_ns,
        "peak_time_ns": _int(peak_time_ns, "peak_time_ns"),
        "onset": stamp(onset_ns),
        "detection": stamp(detection_ns),
        "peak_force_n": _num(peak_force_n, "peak_force_n"),
        "force_after_n": _num(force_after_n, "force_after_n"),
        "drop_fraction": _num(drop_fraction, "drop_fraction"),
        "detector": {str(k): _num_or_none(v, f"detector.{k}") for k, v in detector.items()},
        "trigger": str(trigger),
        "joint": _int_or_none(joint, "joint"),
    }


def _configuration(configuration: Mapping[str, Any] | None) -> dict[str, Any] | None:
    if configuration is None:
        return None
    allowed = ("joint_angles_rad", "transforms")
    out: dict[str, Any] = {}
    for key, value in configuration.items():
        if key not in allowed:
            raise ValueError(f"configuration: unexpected key {key!r}; allowed: {', '.join(allowed)}")
        if value is None:
            continue
        if key == "joint_angles_rad":
            out[key] = [_num(a, f"configuration.joint_angles_rad[{i}]") for i, a in enumerate(value)]
        else:
            transforms = value.tolist() if hasattr(value, "tolist") else value
            out[key] = [
                [[_num(x, "configuration.transforms") for x in row] for row in matrix]
                for matrix in transforms
            ]
    return out


def trial_result(
    *,
    trial_id: int,
    kind: str,
    start_time_ns: int,
    end_time_ns: int,
    outcome: str,
    peak_force_n: float | None,
    slip_mass_kg: float | None,
    predicted_mass_kg: float | None = None,
    distance_m: float | None = None,
    configuration: Mapping[str, Any] | None = None,
    slipped_joint: int | None = None,
    repeat: int = 0,
    lever_arms_m: Sequence[float] | None = None,
) -> dict[str, Any]:
    """A `/rig/trial/result` payload; `configuration` has `joint_angles_rad` and/or `transforms`."""
    start_ns = _int(start_time_ns, "start_time_ns")
    end_ns = _int(end_time_ns, "end_time_ns")
    return {
        "trial_id": _int(trial_id, "trial_id"),
        "kind": _choice(kind, "kind", TRIAL_KINDS),
        "distance_m": _num_or_none(distance_m, "distance_m"),
        "configuration": _configuration(configuration),
        "start": stamp(start_ns),
        "end": stamp(end_ns),
        "start_time_ns": start_ns,
        "end_time_ns": end_ns,
        "peak_force_n": _num_or_none(peak_force_n, "peak_force_n"),
        "slip_mass_kg": _num_or_none(slip_mass_kg, "slip_mass_kg"),
        "predicted_mass_kg": _num_or_none(predicted_mass_kg, "predicted_mass_kg"),
        "slipped_joint": _int_or_none(slipped_joint, "slipped_joint"),
        "outcome": _choice(outcome, "outcome", TRIAL_OUTCOMES),
        "repeat": _int(repeat, "repeat"),
        "lever_arms_m": None
        if lever_arms_m is None
        else [_num(d, f"lever_arms_m[{i}]") for i, d in enumerate(lever_arms_m)],
    }


def _fit_value(key: str, value: Any) -> Any:
    if value is None:
        return None
    if key in _FIT_INTEGER_KEYS:
        return _int(value, key)
    if key == "constant":
        return str(value)
    if key in _FIT_INTERVAL_KEYS:
        bounds = list(value.tolist() if hasattr(value, "tolist") else value)
        if len(bounds) != 2:
            raise ValueError(f"{key}: expected [lower, upper], got {len(bounds)} values")
        return [_num_or_none(b, key) for b in bounds]
    return _num_or_none(value, key)


def estimate(
    *,
    trial_id: int,
    fit: Mapping[str, Any] | None = None,
    joints: Iterable[Mapping[str, Any]] = (),
) -> dict[str, Any]:
    """A `/rig/estimate` payload.

    `fit` is the `rig fit --json` object (missing keys and non-finite values become null; with no
    fit at all, `n` is 0). Each joint is `{joint, capacity_nm, ci_lo_nm, ci_hi_nm}`.
    """
    fit = fit or {}
    unknown = set(fit) - set(FIT_KEYS)
    if unknown:
        raise ValueError(f"fit: unexpected keys {sorted(unknown)}; allowed: {', '.join(FIT_KEYS)}")
    payload: dict[str, Any] = {"trial_id": _int(trial_id, "trial_id")}
    for key in FIT_KEYS:
        payload[key] = _fit_value(key, fit.get(key))
    if payload["n"] is None:
        payload["n"] = 0
    payload["joints"] = [
        {
            "joint": _int(j["joint"], "joints.joint"),
            "capacity_nm": _num_or_none(j.get("capacity_nm"), "joints.capacity_nm"),
            "ci_lo_nm": _num_or_none(j.get("ci_lo_nm"), "joints.ci_lo_nm"),
            "ci_hi_nm": _num_or_none(j.get("ci_hi_nm"), "joints.ci_hi_nm"),
        }
        for j in joints
    ]
    return payload


def log_message(
    *, time_ns: int, level: LogLevel | int, message: str, name: str = "rig", file: str = "", line: int = 0
) -> dict[str, Any]:
    """A `/rig/log` (foxglove.Log) payload."""
    return {
        "timestamp": stamp(time_ns),
        "level": int(LogLevel(level)),
        "message": str(message),
        "name": str(name),
        "file": str(file),
        "line": _int(line, "line"),
    }
