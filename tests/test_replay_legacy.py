"""Logs written before a payload change still replay, with the very same results as on the day."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rig.cli import main

DATA = Path(__file__).parent / "data"


@pytest.mark.parametrize(
    "name",
    [
        "legacy-2026-11-22",  # before the typed records (old /rig/trial/result shape)
        "twins-2026-11-23",  # times as integer *_time_ns fields beside their {sec, nsec} twins
    ],
)
def test_a_log_from_before_a_payload_change_replays_exactly_as_it_did(capsys, name):
    code = main(["replay", str(DATA / f"{name}.mcap"), "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    out.pop("files")
    expected = json.loads((DATA / f"{name}.replay.json").read_text())
    assert out.keys() == expected.keys()
    # Since the configuration measurements: a log from before has none, so their columns are empty.
    for trial in out["trials"]:
        assert trial.pop("configuration_source") is None and trial.pop("bend_corrections") is None
    for key, value in expected.items():
        if key in ("estimate", "redetected_estimate", "online_estimate") and value is not None:
            # Since the estimators: the refit names its estimator (a log from before: the paper's,
            # the only one there was) and carries the paper's fit beside it; the old keys are unchanged.
            assert out[key]["estimator"] == "paper" and out[key].get("paper", value) == value, key
            out[key] = {k: out[key][k] for k in value}
        assert out[key] == value, key
    link = [t for t in out["trials"] if t["kind"] == "link_validation"]
    assert len(link) == 1 and link[0]["joint_angles_rad"] is not None
    assert all(t["start_time_ns"] < t["end_time_ns"] for t in out["trials"])
