"""The servo bus's and the load cell's wire counts are logged per trial (/rig/trial/links) and replayed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rig.cli import main
from rig.hw.dxl.transport import BusStats
from rig.hw.seams import LoadCellLineStats
from rig.log.format import schemas
from rig.records import TrialWireStats

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_a_flaky_bus_shows_its_retries_per_trial_in_the_log_and_in_replay(tmp_path, capsys):
    config = ROOT / "protocols/rigs/faults/flaky-bus.yaml"
    protocol = ROOT / "protocols/smoke.yaml"
    code = main(
        ["run", str(protocol), "--rig", str(config), "--out", str(tmp_path), "--run-id", "f", "--json"]
    )
    assert code == 0
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "f.mcap"), "--json"]) == 0
    links = json.loads(capsys.readouterr().out)["links"]
    assert [entry["trial_id"] for entry in links] == [1, 2]
    for entry in links:
        bus, lines = entry["bus"], entry["loadcell"]
        assert bus["attempts"] == bus["operations"] + bus["retries"]
        assert bus["retries"] == bus["timeouts"] + bus["corrupt"] > 0  # the config drops and corrupts replies
        assert lines["lines_ok"] > 1000 and lines["missing_samples"] == 0
    assert main(["replay", str(tmp_path / "f.mcap")]) == 0
    assert "device links per trial" in capsys.readouterr().out


def test_a_device_without_counts_is_absent_not_null():
    alone = TrialWireStats(trial_id=3)
    assert alone.to_payload() == {"trial_id": 3}
    schemas.check_payload(schemas.TRIAL_LINKS, alone.to_payload())
    both = TrialWireStats(
        3, BusStats(operations=5, attempts=6, retries=1), LoadCellLineStats(9, 0, 1, 2, 1, 0)
    )
    schemas.check_payload(schemas.TRIAL_LINKS, both.to_payload())
    assert TrialWireStats.from_payload(both.to_payload()) == both
    # A table read back gives an absent part as all-missing values: decoded as absent.
    assert (
        TrialWireStats.from_payload({"trial_id": 3, "bus": dict.fromkeys(both.to_payload()["bus"])}) == alone
    )
    schema = schemas.TOPICS[schemas.TRIAL_LINKS].schema
    assert schema["required"] == ["trial_id"]
    assert all(
        isinstance(s["type"], str)
        for part in ("bus", "loadcell")
        for s in schema["properties"][part]["properties"].values()
    )


def test_bus_stats_since_an_earlier_snapshot():
    earlier = BusStats(operations=10, attempts=12, retries=2, timeouts=1, corrupt=1)
    later = BusStats(operations=15, attempts=18, retries=3, timeouts=1, corrupt=2, reboots=1)
    assert later.since(earlier) == BusStats(operations=5, attempts=6, retries=1, corrupt=1, reboots=1)
    assert earlier.since(later) == earlier  # counters restarted: all of these
    assert BusStats(operations=4).clean and not later.clean
