"""The MCAP topic contract: well-formed schemas, valid builder output, a checker that rejects violations."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rig.hw.seams import LoadCellSample, ServoState
from rig.log import schemas as S
from rig.log.examples import example_payloads

EPOCH_NS = 1_767_225_600_123_456_789

EXPECTED = {
    "/rig/loadcell": "rig.LoadCellSample",
    "/rig/servo/state": "rig.ServoState",
    "/rig/servo/command": "rig.ServoCommand",
    "/rig/trial/state": "rig.TrialState",
    "/rig/slip": "rig.SlipEvent",
    "/rig/trial/result": "rig.TrialResult",
    "/rig/estimate": "rig.Estimate",
    "/rig/log": "foxglove.Log",
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
def test_schemas_and_payloads_pass_jsonschema_when_installed(topic):
    jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is not a dependency")
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
    assert [p.value for p in S.TrialPhase] == [
        "idle",
        "connecting",
        "taring",
        "bending",
        "prompting",
        "ramp_fast",
        "ramp_slow",
        "unloading",
        "resetting",
        "pausing",
        "done",
        "aborted",
        "faulted",
    ]


def test_timestamps_split_exactly():
    assert S.stamp(EPOCH_NS) == {"sec": 1_767_225_600, "nsec": 123_456_789}
    slip = sample_payloads()[S.SLIP]
    assert slip["onset"] == {"sec": 1_767_225_600, "nsec": 123_456_789}
    assert slip["detection"]["nsec"] == 128_456_789
    result = sample_payloads()[S.TRIAL_RESULT]
    assert result["end"] == {"sec": 1_767_225_609, "nsec": 123_456_789}


def test_builders_coerce_numpy_and_null_non_finite_optionals():
    payload = S.loadcell_sample(raw=np.int32(5), force_n=np.float32(1.5), seq=np.int64(9))
    assert type(payload["raw"]) is int and type(payload["force_n"]) is float and type(payload["seq"]) is int
    estimate = sample_payloads()[S.ESTIMATE]
    assert estimate["r2"] is None  # NaN where not defined becomes null
    assert estimate["k_ci"] == [0.148, 0.185]
    assert estimate["sse"] is None and estimate["capacity_ci_nm"] is None
    empty = S.estimate(trial_id=0)
    assert empty["n"] == 0 and empty["k"] is None and empty["joints"] == []
    S.check_payload(S.ESTIMATE, empty)


def test_builders_convert_hardware_value_types():
    sample = LoadCellSample(time_ns=EPOCH_NS, raw=-12, force_n=0.5, seq=None, device_time_us=1000)
    assert S.loadcell_payload(sample) == {"seq": None, "raw": -12, "force_n": 0.5, "device_time_us": 1000}
    state = ServoState(1, 0.1, 0.2, 0.3, 4, False, EPOCH_NS)
    payload = S.servo_state_payload(state, "winch")
    assert payload["hardware_error"] == 4 and payload["moving"] is False and payload["role"] == "winch"


@pytest.mark.parametrize(
    ("call", "fragment"),
    [
        (lambda: S.loadcell_sample(raw=1, force_n=float("nan")), "force_n"),
        (lambda: S.loadcell_sample(raw=1.5, force_n=1.0), "raw"),
        (lambda: S.servo_command(servo_id=1, role="w", command="fly", value=1, unit=""), "command"),
        (lambda: S.trial_state(trial_id=1, phase="running"), "phase"),
        (
            lambda: S.trial_result(
                trial_id=1,
                kind="x",
                start_time_ns=0,
                end_time_ns=1,
                outcome="slip",
                peak_force_n=1,
                slip_mass_kg=1,
            ),
            "kind",
        ),
        (lambda: S.estimate(trial_id=1, fit={"kk": 1}), "kk"),
        (lambda: S.estimate(trial_id=1, fit={"k_ci": [1, 2, 3]}), "k_ci"),
        (lambda: S.log_message(time_ns=0, level=9, message="x"), "9"),
        (lambda: S.stamp(-1), "before the epoch"),
    ],
)
def test_builders_reject_bad_values_naming_the_field(call, fragment):
    with pytest.raises(ValueError, match=fragment):
        call()


@pytest.mark.parametrize(
    ("topic", "change", "fragment"),
    [
        (S.LOADCELL, {"force_n": float("nan")}, "not finite"),
        (S.LOADCELL, {"force_n": float("inf")}, "not finite"),
        (S.LOADCELL, {"raw": 2**53}, "exceeds"),
        (S.LOADCELL, {"raw": True}, "bool"),
        (S.LOADCELL, {"raw": np.int64(3)}, "not a JSON type"),
        (S.LOADCELL, {"extra": 1}, "unexpected key 'extra'"),
        (S.SERVO_STATE, {"moving": 1}, "moving"),
        (S.TRIAL_STATE, {"phase": "flying"}, "phase"),
        (S.SLIP, {"onset": {"sec": 1, "nsec": 10**9}}, "onset.nsec"),
        (S.SLIP, {"detector": {"w": "x"}}, "detector.w"),
        (S.ESTIMATE, {"joints": [{"joint": 1}]}, "missing required key 'capacity_nm'"),
        (S.LOG, {"level": 7}, "level"),
    ],
)
def test_checker_rejects_violations(topic, change, fragment):
    payload = {**sample_payloads()[topic], **change}
    with pytest.raises(ValueError, match=fragment):
        S.check_payload(topic, payload)


def test_checker_requires_every_key_and_knows_topics():
    payload = dict(sample_payloads()[S.LOADCELL])
    del payload["seq"]
    with pytest.raises(ValueError, match="missing required key 'seq'"):
        S.check_payload(S.LOADCELL, payload)
    with pytest.raises(KeyError, match="unknown topic"):
        S.check_payload("/rig/nope", payload)


def test_epoch_ns_fields_may_exceed_2_53_but_other_integers_may_not():
    slip = sample_payloads()[S.SLIP]
    assert slip["onset_time_ns"] > 2**53
    S.check_payload(S.SLIP, slip)
    with pytest.raises(ValueError, match="exceeds"):
        S.check_payload(S.SLIP, {**slip, "trial_id": 2**60})


@given(
    raw=st.integers(-(2**31), 2**31),
    force_n=st.floats(allow_nan=True, allow_infinity=True, width=64),
    seq=st.one_of(st.none(), st.integers(0, 2**32)),
)
def test_loadcell_builder_either_raises_or_satisfies_the_schema(raw, force_n, seq):
    try:
        payload = S.loadcell_sample(raw=raw, force_n=force_n, seq=seq)
    except ValueError:
        assert not math.isfinite(force_n)
        return
    S.check_payload(S.LOADCELL, payload)
    assert json.loads(json.dumps(payload, allow_nan=False)) == payload
