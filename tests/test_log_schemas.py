"""The MCAP topic contract: schemas derived from the records, payloads that satisfy them (jsonschema)."""

from __future__ import annotations

import dataclasses
import json
import math

import jsonschema
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader

from rig.hw.seams import LoadCellSample, ServoState
from rig.log.format import schemas as S
from rig.log.format.encoding import MESSAGE_ENCODING, SCHEMA_ENCODING
from rig.log.format.examples import example_payloads
from rig.records import (
    Estimate,
    JointCapacity,
    LogLevel,
    LogMessage,
    ServoCommand,
    SlipMessage,
    TrialPhase,
    TrialResult,
    TrialState,
    stamp,
)

EPOCH_NS = 1_767_225_600_123_456_789

EXPECTED = {
    "/rig/loadcell": "rig.LoadCellSample",
    "/rig/servo/state": "rig.ServoState",
    "/rig/servo/command": "rig.ServoCommand",
    "/rig/trial/state": "rig.TrialState",
    "/rig/slip": "rig.SlipEvent",
    "/rig/trial/result": "rig.TrialResult",
    "/rig/estimate": "rig.Estimate",
    "/rig/trial/links": "rig.TrialLinkStats",
    "/rig/log": "foxglove.Log",
    "/rig/link/frames": "foxglove.FrameTransforms",
    "/rig/link/scene": "foxglove.SceneUpdate",
    "/rig/configuration/measured": "rig.ConfigurationMeasurement",
}


def sample_payloads() -> dict[str, dict]:
    return example_payloads(EPOCH_NS)


def test_every_design_topic_has_its_schema_name():
    assert {t: spec.schema_name for t, spec in S.TOPICS.items()} == EXPECTED


@pytest.mark.parametrize("topic", list(EXPECTED))
def test_schemas_are_foxglove_friendly_json_schema(topic):
    spec = S.TOPICS[topic]
    schema = json.loads(spec.schema_bytes)
    assert schema["type"] == "object"
    assert schema["title"] == spec.schema_name
    assert set(schema["required"]) <= set(schema["properties"])
    # Only internal references are allowed by Foxglove; we use none at all.
    assert "$ref" not in spec.schema_bytes.decode()


@pytest.mark.parametrize("topic", list(EXPECTED))
def test_schemas_and_payloads_pass_jsonschema(topic):
    schema = json.loads(S.TOPICS[topic].schema_bytes)
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(sample_payloads()[topic], schema)


def test_foxglove_log_is_the_exact_well_known_shape():
    schema = S.TOPICS[S.LOG].schema
    assert schema["required"] == ["timestamp", "level", "message", "name", "file", "line"]
    assert [alt["const"] for alt in schema["properties"]["level"]["oneOf"]] == [0, 1, 2, 3, 4, 5]
    assert [alt["title"] for alt in schema["properties"]["level"]["oneOf"]] == [
        "UNKNOWN",
        "DEBUG",
        "INFO",
        "WARNING",
        "ERROR",
        "FATAL",
    ]
    assert set(schema["properties"]["timestamp"]["properties"]) == {"sec", "nsec"}


@pytest.mark.parametrize("topic", list(EXPECTED))
def test_builders_make_valid_strict_json(topic):
    payload = sample_payloads()[topic]
    S.check_payload(topic, payload)
    text = json.dumps(payload, allow_nan=False)
    assert json.loads(text) == json.loads(json.dumps(payload))


def test_phase_enum_matches_the_runner_contract():
    assert [p.value for p in TrialPhase] == [
        "idle", "connecting", "taring", "bending", "prompting", "ramp_fast", "ramp_slow",
        "unloading", "resetting", "pausing", "done", "aborted", "faulted",
    ]  # fmt: skip


def test_timestamps_split_exactly():
    assert stamp(EPOCH_NS) == {"sec": 1_767_225_600, "nsec": 123_456_789}
    slip = sample_payloads()[S.SLIP]
    assert slip["onset"] == {"sec": 1_767_225_600, "nsec": 123_456_789}
    assert slip["detection"]["nsec"] == 128_456_789
    assert slip["peak"] == {"sec": 1_767_225_600, "nsec": 122_456_789}
    result = sample_payloads()[S.TRIAL_RESULT]
    assert result["end"] == {"sec": 1_767_225_609, "nsec": 123_456_789}
    with pytest.raises(ValueError, match="before the epoch"):
        stamp(-1)


@pytest.mark.parametrize(
    ("record", "schema_name"),
    [
        (ServoCommand, "rig.ServoCommand"),
        (TrialState, "rig.TrialState"),
        (TrialResult, "rig.TrialResult"),
    ],
)
def test_schema_properties_are_the_record_fields_with_times_as_stamps(record, schema_name):
    names = [f.removesuffix("_time_ns") for f in record.__dataclass_fields__]
    topic = next(t for t, spec in S.TOPICS.items() if spec.schema_name == schema_name)
    properties = S.TOPICS[topic].schema["properties"]
    assert list(properties) == names
    for name in record.__dataclass_fields__:
        if name.endswith("_time_ns"):
            assert properties[name.removesuffix("_time_ns")]["required"] == ["sec", "nsec"]


def test_slip_schema_holds_the_detector_event_fields():
    props = S.TOPICS[S.SLIP].schema["properties"]
    from model.slip_detector import SlipEvent

    event_fields = {f.removesuffix("_time_ns") for f in SlipEvent.__dataclass_fields__}
    assert event_fields <= set(props)
    assert {"trial_id", "detector", "joint", "onset", "detection", "peak"} <= set(props)
    assert not any(name.endswith("_time_ns") for name in props)


@pytest.mark.parametrize("topic", [S.SERVO_COMMAND, S.TRIAL_STATE, S.SLIP, S.TRIAL_RESULT, S.ESTIMATE])
def test_records_round_trip_through_their_payloads(topic):
    decoders = {
        S.SERVO_COMMAND: ServoCommand,
        S.TRIAL_STATE: TrialState,
        S.SLIP: SlipMessage,
        S.TRIAL_RESULT: TrialResult,
        S.ESTIMATE: Estimate,
    }
    payload = sample_payloads()[topic]
    record = decoders[topic].from_payload(payload)
    assert record.to_payload() == payload


def test_trial_result_journal_form_round_trips_and_keeps_its_key_order():
    result = TrialResult.from_payload(sample_payloads()[S.TRIAL_RESULT])
    journal = result.to_json()
    assert list(journal)[:3] == ["trial_id", "kind", "repeat"] and list(journal)[-2:] == ["tare_n", "reason"]
    assert TrialResult.from_json(json.loads(json.dumps(journal))) == result


def test_payloads_of_the_pre_release_formats_are_refused_naming_what_is_missing():
    # No shims: a /rig/trial/result with integer times and no `start` stamp, a slip without its
    # `kind` or stamps, an estimate without its estimator (logs before 2026-11-23 / 11-27).
    result = {k: v for k, v in sample_payloads()[S.TRIAL_RESULT].items() if k not in ("start", "end")}
    with pytest.raises(KeyError, match="start"):
        TrialResult.from_payload({**result, "start_time_ns": EPOCH_NS, "end_time_ns": EPOCH_NS + 1})
    slip = sample_payloads()[S.SLIP]
    with pytest.raises(KeyError, match="kind"):
        SlipMessage.from_payload({k: v for k, v in slip.items() if k != "kind"})
    with pytest.raises(KeyError, match="detection"):
        old_slip = {k: v for k, v in slip.items() if k != "detection"}
        SlipMessage.from_payload({**old_slip, "detection_time_ns": EPOCH_NS})
    estimate = {k: v for k, v in sample_payloads()[S.ESTIMATE].items() if k != "estimator"}
    with pytest.raises(KeyError, match="estimator"):
        Estimate.from_payload(estimate)


def test_estimate_payload_leaves_out_what_is_undefined():
    estimate = sample_payloads()[S.ESTIMATE]
    assert "r2" not in estimate  # NaN where not defined: the field is absent, never null
    assert estimate["k_ci"] == [0.148, 0.185] and estimate["capacity_bounded"] is True
    empty = Estimate(trial_id=0, fit=None).to_payload()
    assert empty["n"] == 0 and "k" not in empty and empty["joints"] == []
    assert empty["capacity_bounded"] is False
    assert None not in empty.values()
    S.check_payload(S.ESTIMATE, empty)
    assert Estimate.from_payload(empty).fit is None
    joint = Estimate(1, None, (JointCapacity(1, None, None, None),)).to_payload()["joints"][0]
    assert joint == {"joint": 1}
    assert JointCapacity.from_json(joint) == JointCapacity(1, None, None, None)


def test_a_pair_with_an_undefined_bound_is_left_out_whole():
    fit = Estimate.from_payload(sample_payloads()[S.ESTIMATE]).fit
    assert fit is not None
    unbounded = dataclasses.replace(fit, capacity_ci_nm=(1.0, math.inf))
    payload = Estimate(2, unbounded).to_payload()
    assert "capacity_ci_nm" not in payload and payload["capacity_bounded"] is False
    assert payload["capacity_nm"] == fit.capacity_nm
    S.check_payload(S.ESTIMATE, payload)
    decoded = Estimate.from_payload(payload).fit
    assert decoded is not None and all(math.isnan(b) for b in decoded.capacity_ci_nm)


def test_missing_values_read_back_from_a_table_as_none_decode():
    # Replay reads payloads back from columns, where an absent field is None.
    state = TrialState.from_payload({"trial_id": None, "phase": "idle", "step": None})
    assert state == TrialState(None, TrialPhase.IDLE, None)
    estimate = dict(sample_payloads()[S.ESTIMATE], r2=None, scatter_model=None, paper_k_ci=[None, None])
    decoded = Estimate.from_payload(estimate)
    assert decoded.fit is not None and math.isnan(decoded.fit.r2) and decoded.scatter_model is None
    assert decoded.paper_k_ci is not None and all(math.isnan(b) for b in decoded.paper_k_ci)
    empty = {"trial_id": 1, "n": 0, "k": None, "k_ci": None, "joints": [], "estimator": "auto"}
    assert Estimate.from_payload(empty).fit is None
    command = ServoCommand.from_payload({"servo_id": 1, "role": "winch", "command": "reboot", "value": None})
    assert command.value is None


def test_a_load_cell_row_holds_every_field_of_a_sample_but_its_time():
    """The one sample shape: a `LoadCellSample` is logged as a row of its fields, its time the log time."""
    assert set(S.ROW_FIELDS[S.LOADCELL]) == set(LoadCellSample._fields) - {"time_ns"}
    assert S.ROW_FIELDS[S.LOADCELL] == tuple(S.loadcell_sample(raw=1, force_n=1.0, seq=2, device_time_us=3))


def test_builders_coerce_numpy():
    payload = S.loadcell_sample(raw=np.int32(5), force_n=np.float32(1.5), seq=np.int64(9))
    assert type(payload["raw"]) is int and type(payload["force_n"]) is float and type(payload["seq"]) is int
    command = ServoCommand(np.int64(3), "winch", "torque", np.float32(1.0), "").to_payload()
    assert type(command["servo_id"]) is int and type(command["value"]) is float


def test_builders_convert_hardware_value_types():
    sample = LoadCellSample(time_ns=EPOCH_NS, raw=-12, force_n=0.5, seq=None, device_time_us=1000)
    row = tuple(getattr(sample, name) for name in S.ROW_FIELDS[S.LOADCELL])
    assert S.row_payload(S.LOADCELL, row) == {"raw": -12, "force_n": 0.5, "device_time_us": 1000}
    state = ServoState(1, 0.1, 0.2, 0.3, 4, False, EPOCH_NS)
    payload = S.servo_state_payload(state, "winch")
    assert payload["hardware_error"] == 4 and payload["moving"] is False and payload["role"] == "winch"
    S.check_payload(S.SERVO_STATE, payload)


@pytest.mark.parametrize(
    ("call", "fragment"),
    [
        (lambda: S.loadcell_sample(raw=1, force_n=float("nan")), "force_n"),
        (lambda: S.loadcell_sample(raw=1.5, force_n=1.0), "raw"),
        (lambda: ServoCommand(1, "w", "fly", 1.0, "").to_payload(), "fly"),
        (lambda: TrialState(1, "running").to_payload(), "running"),
        (lambda: LogMessage(0, 9, "x").to_payload(), "9"),
        (lambda: TrialResult.from_json({"trial_id": 1, "kind": "both"}), "both"),
    ],
)
def test_records_reject_bad_values_naming_them(call, fragment):
    with pytest.raises(ValueError, match=fragment):
        call()


def test_log_levels_are_foxglove_levels():
    assert LogMessage(EPOCH_NS, LogLevel.ERROR, "x").to_payload()["level"] == 4


@pytest.mark.parametrize(
    ("topic", "change", "fragment"),
    [
        (S.LOADCELL, {"force_n": float("nan")}, "not finite"),
        (S.LOADCELL, {"force_n": float("inf")}, "not finite"),
        (S.LOADCELL, {"raw": 2**60}, "is greater than the maximum"),
        (S.LOADCELL, {"raw": True}, "not of type"),
        (S.LOADCELL, {"raw": np.int64(3)}, "not a JSON type"),
        (S.LOADCELL, {"extra": 1}, "Additional properties"),
        (S.SERVO_COMMAND, {"command": "fly"}, "is not one of"),
        (S.TRIAL_STATE, {"phase": "running"}, "is not one of"),
        (S.TRIAL_RESULT, {"kind": "both"}, "is not one of"),
        (S.ESTIMATE, {"k_ci": [1.0]}, "is too short"),
    ],
)
def test_checker_rejects_violations(topic, change, fragment):
    payload = {**sample_payloads()[topic], **change}
    with pytest.raises(ValueError, match=fragment):
        S.check_payload(topic, payload)


def test_checker_requires_every_key_but_the_optional_ones_and_knows_topics():
    payload = sample_payloads()[S.LOADCELL]
    del payload["raw"]
    with pytest.raises(ValueError, match="'raw' is a required property"):
        S.check_payload(S.LOADCELL, payload)
    optional = sample_payloads()[S.LOADCELL]
    del optional["seq"]  # a missing value is an absent field
    S.check_payload(S.LOADCELL, optional)
    with pytest.raises(ValueError, match="None is not of type 'integer'"):
        S.check_payload(S.LOADCELL, dict(optional, seq=None))  # ... never null
    with pytest.raises(KeyError, match="unknown topic"):
        S.check_payload("/rig/nope", payload)


def test_no_payload_integer_may_exceed_2_53_and_times_are_stamps():
    slip = sample_payloads()[S.SLIP]
    assert slip["onset"]["sec"] < 2**53 and "onset_time_ns" not in slip
    S.check_payload(S.SLIP, slip)
    with pytest.raises(ValueError, match="trial_id"):
        S.check_payload(S.SLIP, {**slip, "trial_id": 2**60})
    with pytest.raises(ValueError, match="Additional properties"):  # the old integer form is gone
        S.check_payload(S.SLIP, {**slip, "onset_time_ns": EPOCH_NS})
    with pytest.raises(ValueError, match="nsec"):
        S.check_payload(S.SLIP, {**slip, "onset": {"sec": 1, "nsec": 10**9}})


@pytest.mark.parametrize(
    ("stamp_value", "fragment"),
    [({"sec": 1, "nsec": -1}, "nsec"), ({"sec": 1}, "onset.nsec"), (5, "timestamp"), (None, "onset")],
)
def test_a_bad_stamp_is_refused_naming_the_field(stamp_value, fragment):
    slip = {**sample_payloads()[S.SLIP], "onset": stamp_value}
    with pytest.raises((ValueError, KeyError), match=fragment):
        SlipMessage.from_payload(slip)


@given(
    raw=st.one_of(st.integers(-(2**40), 2**40), st.floats(allow_nan=True)),
    force_n=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 5)),
    seq=st.one_of(st.none(), st.integers(0, 2**32)),
)
def test_loadcell_builder_either_raises_or_satisfies_the_schema(raw, force_n, seq):
    try:
        payload = S.loadcell_sample(raw=raw, force_n=force_n, seq=seq)
    except ValueError:
        return
    S.check_payload(S.LOADCELL, payload)


@pytest.mark.slow  # the default run (about 8 s, shared with other tests), then 80,000 payloads
def test_every_payload_of_a_default_run_is_javascript_exact_and_valid_against_its_advertised_schema(
    default_run_log,
):
    too_big: list[str] = []

    def parse_int(text: str) -> int:
        value = int(text)
        if abs(value) > S.MAX_SAFE_INT:
            too_big.append(text)
        return value

    validators: dict[int, jsonschema.Draft202012Validator] = {}
    counts: dict[str, int] = {}
    with default_run_log.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None and schema.encoding == SCHEMA_ENCODING, channel.topic
            assert channel.message_encoding == MESSAGE_ENCODING
            if schema.id not in validators:
                advertised = json.loads(schema.data)
                assert advertised == S.TOPICS[channel.topic].schema, channel.topic
                validators[schema.id] = jsonschema.Draft202012Validator(advertised)
            payload = json.loads(message.data, parse_int=parse_int)
            errors = list(validators[schema.id].iter_errors(payload))
            assert not errors, (channel.topic, payload, errors[0].message)
            assert not too_big, (channel.topic, too_big)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert set(counts) == set(S.TOPICS)  # every topic was walked
    assert counts[S.SLIP] == counts[S.TRIAL_RESULT] == 24
