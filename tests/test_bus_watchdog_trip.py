"""A Bus Watchdog tripped mid-run by a host pause is found, cleared, logged and counted; the run goes on.

The simulated rig's `host pause` fault stops the host for longer than the servos' watchdog while the
emulated servos go on: they stop where they are and refuse goals. The checks read the log and the
simulator's truth: the trial is repeated, the run completes, and the line ends slack.
"""

from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import make_reader

from rig.hw.dxl.bus import DynamixelServoBus
from rig.log.format import schemas
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]
PAUSE = """\
extends: simulated
name: pause
simulation:
  faults:
    - {device: host, kind: pause, at_s: 3.0, duration_s: 1.5}
"""


def _run(tmp_path: Path, rig_text: str):
    rig = tmp_path / "rig.yaml"
    rig.write_text(rig_text)
    request = RunRequest(
        protocol_path=ROOT / "protocols" / "smoke.yaml", rig_path=rig, out_dir=tmp_path, seed=0, run_id="p"
    )
    prepared = prepare_run(request)
    sim = open_simulated_rig(prepared)
    report = execute_run(prepared, sim, SilentProgress())
    return prepared, sim, report


def _messages(log: Path, topic: str) -> list[dict]:
    with log.open("rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


def test_a_host_pause_trips_the_watchdog_which_is_cleared_and_the_trial_repeated(tmp_path):
    prepared, sim, report = _run(tmp_path, PAUSE)
    assert report.exit_code == 0, report.reason
    assert report.completed == 2
    assert prepared.journal.retried_trials == [1]
    truth = report.truth
    assert truth is not None and truth.final_tension_n < 0.5 and truth.torque_off
    assert sim.devices.faults.fired == ["host pause"]
    log = tmp_path / "p.mcap"
    notes = [m["message"] for m in _messages(log, schemas.LOG)]
    assert any("servo 1 (winch): Bus Watchdog tripped" in n and "cleared and re-armed" in n for n in notes)
    assert any(n.startswith("control tick late by 1500.0 ms") for n in notes)
    links = {m["trial_id"]: m for m in _messages(log, schemas.TRIAL_LINKS)}
    assert links[1]["bus"]["watchdog_trips"] == 2  # winch and bender
    assert links[1]["control"]["late_ticks"] == 1
    assert links[1]["control"]["max_lateness_us"] == 1_500_000
    assert links[2]["bus"]["watchdog_trips"] == 0 and links[2]["control"]["late_ticks"] == 0


def test_without_the_check_the_tripped_winch_refuses_its_goals(tmp_path, monkeypatch):
    # The negative control (the behaviour before the check): a driver that never reads register 98
    # leaves the winch refusing every goal after the pause, the release included, so the ramp
    # times out and the line is left loaded where the watchdog stopped the winch.
    monkeypatch.setattr(DynamixelServoBus, "_check_watchdogs_after_quiet", lambda self: None)
    _, _, report = _run(tmp_path, PAUSE)
    assert report.exit_code == 1
    assert "ramp_until_slip exceeded its timeout" in (report.reason or "")
    assert report.truth is not None and report.truth.final_tension_n > 5.0
