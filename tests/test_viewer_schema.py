"""Every schema the rig advertises stays inside the subset Foxglove's and Lichtblick's reader accepts.

The reader turns a channel's JSON Schema into panel fields and refuses the whole channel on one
construct it does not know (`rig.log.format.viewer_schema`). These tests check the advertised schemas, the
checker itself (each refused construct is caught), and the messages of a real run: no null
anywhere, since a missing value is an absent field.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from mcap.reader import make_reader

from rig.log.format import schemas
from rig.log.format.viewer_schema import problems


@pytest.mark.parametrize("topic", list(schemas.TOPICS))
def test_every_advertised_schema_is_inside_the_viewer_subset(topic):
    assert problems(schemas.TOPICS[topic].schema) == []


def _with_field(field: dict[str, Any]) -> dict[str, Any]:
    return {"type": "object", "properties": {"ok": {"type": "number"}, "x": field}}


@pytest.mark.parametrize(
    ("field", "fragment"),
    [
        ({"type": ["integer", "null"]}, "x: type ['integer', 'null']"),
        ({"type": "null"}, "x: type 'null'"),
        ({"enum": ["a", "b"]}, "x: type None"),
        ({"type": "string", "contentEncoding": "base16"}, "contentEncoding 'base16'"),
        (
            {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
            "x[]: item type 'array'",
        ),
        ({"type": "array", "items": [{"type": "number"}]}, "x: items must be one schema"),
        ({"type": "array"}, "x: items must be one schema"),
        ({"oneOf": [{"title": "A", "const": "a"}]}, "oneOf[0] must be"),
        ({"oneOf": [{"const": 1}]}, "oneOf[0] must be"),
        ({"oneOf": [{"title": "T", "const": True}]}, "oneOf[0] must be"),
        ({"type": "object", "properties": {"y": {"type": ["number", "null"]}}}, "x.y: type"),
        ({"type": "array", "items": {"type": "object", "properties": {"z": {}}}}, "x[].z: type None"),
        ({"$ref": "#/$defs/thing", "type": "object"}, "x: $ref is not read"),
        ({"type": "number", "anyOf": [{"minimum": 0}]}, "x: anyOf is not read"),
        ({"type": "string", "const": "fixed"}, "x: const outside oneOf"),
    ],
)
def test_the_checker_refuses_what_the_viewer_refuses(field, fragment):
    found = problems(_with_field(field))
    assert found and fragment in found[0], found


def test_the_checker_accepts_what_the_viewer_reads():
    schema = {
        "type": "object",
        "properties": {
            "flag": {"type": "boolean"},
            "name": {"type": "string", "enum": ["a", "b"]},
            "blob": {"type": "string", "contentEncoding": "base64"},
            "count": {"type": "integer", "minimum": 0},
            "level": {"oneOf": [{"title": "LOW", "const": 0}, {"title": "HIGH", "const": 1}]},
            "when": {"type": "object", "properties": {"sec": {"type": "integer"}}},
            "values": {"type": "array", "items": {"type": "number"}},
            "rows": {"type": "array", "items": {"type": "object", "properties": {"v": {"type": "string"}}}},
            "by_name": {"type": "object", "additionalProperties": {"type": "number"}},
        },
    }
    assert problems(schema) == []
    assert problems({"type": "array"}) == ["(root): type must be \"object\", not 'array'"]


def test_the_schemas_of_logs_before_the_subset_are_caught():
    # Schemas of 2026-11-22 had `["integer", "null"]` fields: the very files that showed empty panels
    # in Lichtblick (that day's /rig/loadcell schema as logged, descriptions left out): must be caught.
    old_loadcell = {
        "type": "object",
        "title": "rig.LoadCellSample",
        "properties": {
            "seq": {"type": ["integer", "null"]},
            "raw": {"type": "integer"},
            "force_n": {"type": "number"},
            "device_time_us": {"type": ["integer", "null"]},
        },
        "required": ["seq", "raw", "force_n", "device_time_us"],
    }
    found = problems(old_loadcell)
    assert len(found) == 2 and all("null" in p for p in found), found


def _nulls(value: Any, path: str) -> list[str]:
    if value is None:
        return [path]
    if isinstance(value, dict):
        return [p for key, item in value.items() for p in _nulls(item, f"{path}.{key}")]
    if isinstance(value, list):
        return [p for i, item in enumerate(value) for p in _nulls(item, f"{path}[{i}]")]
    return []


def test_a_run_logs_no_null_on_any_topic(default_run_log):
    nulls: dict[str, list[str]] = {}
    seen: set[str] = set()
    bounded = []
    with default_run_log.open("rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            seen.add(channel.topic)
            payload = json.loads(message.data)
            found = _nulls(payload, "")
            if found:
                nulls.setdefault(channel.topic, []).extend(found[:3])
            if channel.topic == schemas.ESTIMATE:
                bounded.append(payload["capacity_bounded"])
                if payload["capacity_bounded"]:  # the flag the layout's estimate plot filters on
                    assert len(payload["capacity_ci_nm"]) == 2 and payload["capacity_nm"] > 0
    assert nulls == {}
    assert bounded[0] is False and all(bounded[2:]), bounded  # no fit before 2 slips
    assert {schemas.LOADCELL, schemas.TRIAL_STATE, schemas.ESTIMATE, schemas.TRIAL_RESULT} <= seen
