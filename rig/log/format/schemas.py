"""The MCAP topic contract: topic names and JSON Schemas, derived from the typed records.

Every topic is JSON-encoded with a `jsonschema` schema whose top level is an object (Foxglove needs
that). The schemas are not written by hand: each is derived from the fields and type hints of the
record that makes the payload (`rig.records`, and the seams' `ServoState` and `LoadCellSample`),
so a field added to a record appears in its schema. Conventions: every schema stays inside the
subset Foxglove's and Lichtblick's schema reader understands (`rig.log.format.viewer_schema`: one `type`
string per field, enums of numbers as `oneOf` consts); a missing value (`X | None` in the record, a
non-finite number) is an *absent field*, never null and never NaN, so optional fields are left out
of `required`; every integer stays below 2**53 so that JavaScript readers see it exactly; a
record's epoch-nanosecond field `*_time_ns` appears as a `{sec, nsec}` timestamp named without the
suffix (Foxglove's time type). `/rig/log` is Foxglove's well-known `foxglove.Log`, kept field for
field.

`/rig/loadcell` (1 kHz) is logged as rows (`ROW_FIELDS`), not records: no dict per sample.
"""

from __future__ import annotations

import functools
import json
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, fields, is_dataclass
from enum import Enum
from typing import Any

from model.fit import FitSummary
from model.slip_detector import SlipEvent
from rig.hw.dxl.transport import BusStats
from rig.hw.seams import LoadCellLineStats, LoadCellSample, ServoState
from rig.log.format.scene_schemas import frame_transforms_schema, scene_update_schema
from rig.records import (
    ConfigurationMeasurement,
    ControlTickStats,
    Estimate,
    JointCapacity,
    LogLevel,
    ServoCommand,
    SlipMessage,
    TrialResult,
    TrialState,
    TrialWireStats,
    finite_number,
    integer,
    integer_or_none,
    present,
    stamp_name,
)

MAX_SAFE_INT = 2**53 - 1  # largest integer a JavaScript double holds exactly

LOADCELL = "/rig/loadcell"
SERVO_STATE = "/rig/servo/state"
SERVO_COMMAND = "/rig/servo/command"
TRIAL_STATE = "/rig/trial/state"
SLIP = "/rig/slip"
TRIAL_RESULT = "/rig/trial/result"
ESTIMATE = "/rig/estimate"
TRIAL_LINKS = "/rig/trial/links"
LOG = "/rig/log"
LINK_FRAMES = "/rig/link/frames"
LINK_SCENE = "/rig/link/scene"
CONFIGURATION_MEASURED = "/rig/configuration/measured"

# ---------------------------------------------------------------------------------------------
# Deriving schemas from type hints

_TIMESTAMP = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}


def _optional_inner(hint: Any) -> Any | None:
    """`X` for a hint `X | None`; None for any other hint."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = typing.get_args(hint)
        inner = [a for a in args if a is not type(None)]
        if len(inner) != 1 or type(None) not in args:
            raise TypeError(f"unsupported union {hint!r}: only `X | None` (an optional field)")
        return inner[0]
    return None


def _type_schema(name: str, hint: Any) -> dict[str, Any]:
    """The JSON Schema of one field's values from its type hint (`X | None` only at the top: `Fields`)."""
    if _optional_inner(hint) is not None:
        raise TypeError(
            f"{name}: an optional value inside a container has no JSON form (use an absent field)"
        )
    args = typing.get_args(hint)
    if isinstance(hint, type) and issubclass(hint, Enum):
        return {"type": "string", "enum": [m.value for m in hint]}
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        if name.endswith("_time_ns"):
            return dict(_TIMESTAMP)
        return {"type": "integer", "maximum": MAX_SAFE_INT, "minimum": -MAX_SAFE_INT}
    if hint is float:
        return {"type": "number"}
    if hint is str:
        return {"type": "string"}
    origin = typing.get_origin(hint)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return {"type": "array", "items": _type_schema(name, args[0])}
        return {
            "type": "array",
            "items": _type_schema(name, args[0]),
            "minItems": len(args),
            "maxItems": len(args),
        }
    if origin in (Mapping, dict, typing.Mapping):
        value = args[1]
        inner = _optional_inner(value)  # a None value is left out of the map, like an absent field
        return {
            "type": "object",
            "additionalProperties": _type_schema(name, value if inner is None else inner),
        }
    raise TypeError(f"{name}: no JSON Schema for {hint!r}")


@dataclass(frozen=True)
class Fields:
    """The payload fields of a record: `{payload name: schema}` in field order, and which may be absent."""

    properties: dict[str, Any]
    optional: frozenset[str] = frozenset()

    def __add__(self, other: Fields) -> Fields:
        return Fields({**self.properties, **other.properties}, self.optional | other.optional)

    def with_field(self, name: str, schema: dict[str, Any], *, optional: bool = False) -> Fields:
        """These fields and one more (or one replaced)."""
        opt = self.optional | {name} if optional else self.optional - {name}
        return Fields({**self.properties, name: schema}, opt)


def _field_schemas(record: type, *, exclude: tuple[str, ...] = (), optional: bool = False) -> Fields:
    """The payload fields of a dataclass or NamedTuple (`X | None` fields optional; all if asked).

    A `*_time_ns` field is the `{sec, nsec}` timestamp named without the suffix (`records.stamp`).
    """
    hints = typing.get_type_hints(record)
    names = [f.name for f in fields(record)] if is_dataclass(record) else list(record._fields)  # type: ignore[attr-defined]
    properties: dict[str, Any] = {}
    absent: set[str] = set()
    for name in names:
        if name in exclude:
            continue
        hint = hints[name]
        inner = _optional_inner(hint)
        payload_name = stamp_name(name)
        properties[payload_name] = _type_schema(name, hint if inner is None else inner)
        if optional or inner is not None:
            absent.add(payload_name)
    return Fields(properties, frozenset(absent))


def _rig_object(title: str, description: str, payload: Fields) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": payload.properties,
        "required": [name for name in payload.properties if name not in payload.optional],
        "additionalProperties": False,
    }


def _servo_state_fields() -> Fields:
    state = _field_schemas(ServoState, exclude=("time_ns",))
    servo_id = state.properties.pop("servo_id")
    return Fields({"servo_id": servo_id, "role": {"type": "string"}, **state.properties}, state.optional)


def _estimate_fields() -> Fields:
    fit = _field_schemas(FitSummary, optional=True)
    fit = fit.with_field("n", {"type": "integer", "minimum": 0, "maximum": MAX_SAFE_INT})
    joint = _field_schemas(JointCapacity)
    joints = {
        "type": "array",
        "items": {
            "type": "object",
            "properties": joint.properties,
            "required": [name for name in joint.properties if name not in joint.optional],
            "additionalProperties": False,
        },
    }
    return (
        _field_schemas(Estimate, exclude=("fit", "joints"))
        + fit
        + Fields({"joints": joints})
        + Fields({"capacity_bounded": {"type": "boolean"}})
    )


def _trial_links() -> dict[str, Any]:
    """`/rig/trial/links`: the trial id, and each device's counts as an object when it keeps them."""

    def counts(record: type, what: str) -> dict[str, Any]:
        fields_ = _field_schemas(record)
        return {
            "type": "object",
            "description": what,
            "properties": fields_.properties,
            "required": [name for name in fields_.properties if name not in fields_.optional],
            "additionalProperties": False,
        }

    # The schema name is the log contract (docs/formats.md) and keeps "Link"; the record is TrialWireStats.
    return _rig_object(
        "rig.TrialLinkStats",
        "What the device links delivered and lost during one trial; a device that keeps no counts is absent.",
        _field_schemas(TrialWireStats, exclude=("bus", "loadcell", "control"))
        + Fields(
            {
                "bus": counts(BusStats, "the servo bus's exchanges during the trial"),
                "loadcell": counts(LoadCellLineStats, "the load cell's serial lines during the trial"),
                "control": counts(ControlTickStats, "the control loop's ticks during the trial"),
            },
            frozenset({"bus", "loadcell", "control"}),
        ),
    )


def _foxglove_log() -> dict[str, Any]:
    # The exact well-known schema (name and fields) that Foxglove's Log panel recognizes.
    return {
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
    }


_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    LOADCELL: (
        "rig.LoadCellSample",
        _rig_object(
            "rig.LoadCellSample",
            "One load-cell sample (log time: its sampling time): seq and device clock [us] when sent.",
            _field_schemas(LoadCellSample, exclude=("time_ns",)),
        ),
    ),
    SERVO_STATE: (
        "rig.ServoState",
        _rig_object("rig.ServoState", "One servo's state from one bus read.", _servo_state_fields()),
    ),
    SERVO_COMMAND: (
        "rig.ServoCommand",
        _rig_object(
            "rig.ServoCommand",
            "A command sent to a servo (log_time = when it was sent); value in unit, absent for reboot.",
            _field_schemas(ServoCommand),
        ),
    ),
    TRIAL_STATE: (
        "rig.TrialState",
        _rig_object(
            "rig.TrialState",
            "A phase change of the runner (trial_id absent outside trials).",
            _field_schemas(TrialState),
        ),
    ),
    SLIP: (
        "rig.SlipEvent",
        _rig_object(
            "rig.SlipEvent",
            "A slip detected in the load-cell signal; detector parameters by name; joint 1-based if known.",
            _field_schemas(SlipMessage, exclude=("event", "detector", "joint", "train_drops"))
            + _field_schemas(SlipEvent)
            + _field_schemas(SlipMessage, exclude=("trial_id", "event")),
        ),
    ),
    TRIAL_RESULT: (
        "rig.TrialResult",
        _rig_object("rig.TrialResult", "The result of one trial.", _field_schemas(TrialResult)),
    ),
    ESTIMATE: (
        "rig.Estimate",
        _rig_object(
            "rig.Estimate",
            "The online estimate after a trial (keys as `rig fit --json`, absent where undefined;"
            " capacity_bounded: capacity_nm and both capacity_ci_nm bounds are present).",
            _estimate_fields(),
        ),
    ),
    TRIAL_LINKS: ("rig.TrialLinkStats", _trial_links()),
    LOG: ("foxglove.Log", _foxglove_log()),
    LINK_FRAMES: ("foxglove.FrameTransforms", frame_transforms_schema()),
    LINK_SCENE: ("foxglove.SceneUpdate", scene_update_schema()),
    CONFIGURATION_MEASURED: (
        "rig.ConfigurationMeasurement",
        _rig_object(
            "rig.ConfigurationMeasurement",
            "A measured link configuration (rad, joint 1 first; uncertainty: sd where known) beside the"
            " commanded one; stage bent (attempt n after the n-th correction) or after_slip.",
            _field_schemas(ConfigurationMeasurement),
        ),
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


@functools.cache
def _validator(topic: str) -> Any:
    from jsonschema import Draft202012Validator  # a test dependency: strict mode only

    return Draft202012Validator(schema_for(topic).schema)


def check_payload(topic: str, payload: Any) -> None:
    """Raise `ValueError` naming the topic and field if `payload` violates its schema or is not strict JSON.

    Uses `jsonschema` (installed with the test extra); `RunLogger` calls this per message only in
    strict mode, which the tests turn on.
    """
    spec = schema_for(topic)
    problem = _not_strict_json(payload, "")
    if problem:
        raise ValueError(f"{topic} ({spec.schema_name}): {problem}")
    errors = sorted(_validator(topic).iter_errors(payload), key=lambda e: list(e.absolute_path))
    if errors:
        where = ".".join(str(p) for p in errors[0].absolute_path) or "payload"
        raise ValueError(f"{topic} ({spec.schema_name}): {where}: {errors[0].message}")


# Keywords a row field's schema may use for `row_passes` to decide on it; any other sends every row
# of its topic to `check_payload`.
_ROW_KEYWORDS = frozenset({"type", "minimum", "maximum", "description", "title"})


@functools.cache
def _row_bounds(topic: str) -> tuple[tuple[frozenset[str], float, float, bool], ...] | None:
    """Per row field: its JSON types, bounds and whether it is required.

    None if a field's schema says more than `_ROW_KEYWORDS`.
    """
    schema = schema_for(topic).schema
    required = set(schema.get("required", ()))
    bounds = []
    for name in ROW_FIELDS[topic]:
        field = schema["properties"][name]
        if not field.keys() <= _ROW_KEYWORDS:
            return None
        low, high = field.get("minimum", -math.inf), field.get("maximum", math.inf)
        bounds.append((frozenset(json_types(field)), low, high, name in required))
    return tuple(bounds)


def row_passes(topic: str, row: tuple[Any, ...]) -> bool:
    """True only if `check_payload` would accept the row's payload; False: ask `check_payload`.

    FAST PATH of strict mode's check of a row (the tests log a million load-cell rows; `jsonschema`
    takes 80 us for each): plain types only, an int or finite float within the field's bounds, a
    None where the field may be absent. Whatever it does not accept goes to `check_payload`, which
    decides and says why; tests/test_log_writer.py checks that it never accepts what that refuses.
    """
    bounds = _row_bounds(topic)
    if bounds is None or len(row) != len(bounds):
        return False
    for value, (types_, low, high, required) in zip(row, bounds, strict=True):
        kind = type(value)
        if value is None:
            if required:
                return False
        elif kind is int:
            if not ("integer" in types_ or "number" in types_) or not low <= value <= high:
                return False
        elif kind is float:
            if "number" not in types_ or not (math.isfinite(value) and low <= value <= high):
                return False
        else:
            return False
    return True


def _not_strict_json(value: Any, path: str) -> str | None:
    """The first value that strict JSON cannot hold (NaN, infinity, a numpy scalar...), named by path."""
    if isinstance(value, Mapping):
        for key, item in value.items():
            problem = _not_strict_json(item, f"{path}.{key}" if path else str(key))
            if problem:
                return problem
        return None
    if isinstance(value, list | tuple):
        for i, item in enumerate(value):
            problem = _not_strict_json(item, f"{path}[{i}]")
            if problem:
                return problem
        return None
    if isinstance(value, float) and not math.isfinite(value):
        return f"{path}: {value} is not finite (use null)"
    if value is None or type(value) in (bool, int, float, str) or isinstance(value, Enum):
        return None
    return f"{path}: {type(value).__name__} is not a JSON type (convert numpy scalars with float()/int())"


def json_types(schema: Mapping[str, Any]) -> tuple[str, ...]:
    """The JSON types a schema fragment allows (empty if it does not say)."""
    t = schema.get("type")
    if t is None:
        return ()
    return (t,) if isinstance(t, str) else tuple(t)


# ---------------------------------------------------------------------------------------------
# Payloads of the seams' value types (the records make their own: `record.to_payload()`)


def loadcell_sample(
    *, raw: int, force_n: float, seq: int | None = None, device_time_us: int | None = None
) -> dict[str, Any]:
    """A `/rig/loadcell` payload."""
    if (
        type(raw) is int
        and type(force_n) is float
        and math.isfinite(force_n)
        and type(seq) is int
        and type(device_time_us) is int
    ):
        # The common case (1 kHz from the driver): already the exact types the checks below produce.
        return {"seq": seq, "raw": raw, "force_n": force_n, "device_time_us": device_time_us}
    return present(
        {
            "seq": integer_or_none(seq, "seq"),
            "raw": integer(raw, "raw"),
            "force_n": finite_number(force_n, "force_n"),
            "device_time_us": integer_or_none(device_time_us, "device_time_us"),
        }
    )


# `/rig/loadcell` (1 kHz) goes to the writer as rows (`RunLogger.log_columns`): a `LoadCellSample`'s
# fields but its time (the log time), in the order of `loadcell_sample`'s JSON object; no dict per
# sample. The writer process and the live view encode a row as that object.
ROW_FIELDS: dict[str, tuple[str, ...]] = {LOADCELL: ("seq", "raw", "force_n", "device_time_us")}


def row_payload(topic: str, row: tuple[Any, ...]) -> dict[str, Any]:
    """The payload of a row of `topic` (`ROW_FIELDS`): its fields by name, None values left out."""
    return present(dict(zip(ROW_FIELDS[topic], row, strict=True)))


TopicsRequest = tuple[str, list[tuple[str, str, bytes]], dict[str, tuple[str, ...]]]


def topics_request() -> TopicsRequest:
    """The first request of a log child process (the MCAP writer, the live server).

    `("topics", [(topic, schema_name, schema_bytes), ...], {topic: row_fields})`: every topic's
    schema, and the fields of the topics logged as rows. The children take them from here rather
    than import this module, which would cost each of them a third of a second at every start.
    """
    topics = [(topic, spec.schema_name, spec.schema_bytes) for topic, spec in TOPICS.items()]
    return ("topics", topics, dict(ROW_FIELDS))


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
        "servo_id": integer(servo_id, "servo_id"),
        "role": str(role),
        "position_rad": finite_number(position_rad, "position_rad"),
        "velocity_rad_s": finite_number(velocity_rad_s, "velocity_rad_s"),
        "current_a": finite_number(current_a, "current_a"),
        "hardware_error": integer(hardware_error, "hardware_error"),
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
