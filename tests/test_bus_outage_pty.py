"""A servo bus that goes quiet, or a host that pauses, mid-ramp: `rig run` against the rig's twin.

Over ptys (`rig sim rig`, tests/test_hardware_path_faults.py). The servos' USB adapter hangs
mid-ramp (the twin's `freeze servos`): the servos hear nothing, their Bus Watchdog trips and holds
the winch; the release keeps trying for `servos.release_patience_s`, verifies the safe state once
the bus answers and the trial is repeated, this time to its slip. A bus silent for longer ends the
run (exit 1) saying what state the winch is in; an adapter pulled out (`unplug servos`) is reported
naming its port. The run itself frozen for longer than the watchdog (a host pause) trips it; the run
clears it. Each test ends on the twin's truth: the line slack and the torque off where the run
verified the safe state, the line loaded and the winch held where it says the line may be loaded.
"""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.conftest import TwinServer
from tests.test_hardware_path_faults import MID_RAMP_N, assert_released, run_to_mid_ramp

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]


def _start(tmp_path: Path, hardware_twin, patience_s: float):
    return run_to_mid_ramp(tmp_path, hardware_twin, "o", servos={"release_patience_s": patience_s})


def _journal(tmp_path: Path) -> dict:
    return json.loads((tmp_path / "out" / "o.journal.json").read_text())


def _notes(tmp_path: Path) -> list[str]:
    with (tmp_path / "out" / "o.mcap").open("rb") as f:
        return [
            json.loads(m.data)["message"] for _, _, m in make_reader(f).iter_messages(topics=["/rig/log"])
        ]


def _assert_repeated_to_its_slip(report: dict, returncode: int, notes: list[str]) -> None:
    """The run recovered: the repeated trial slipped and the run ended with the safe state verified."""
    shown = "\n".join([str(report["reason"]), *(n for n in notes if "late by" not in n)])
    assert returncode == 0, shown
    assert report["safe_state_verified"] is True
    assert [t["outcome"] for t in report["trials"]] == ["slip"], shown


def _assert_held_loaded(twin: TwinServer) -> None:
    """The twin's truth: the winch's torque still on and the line still loaded, as the run warns."""
    truth = twin.stop()
    assert truth["torque_off"] is False
    assert truth["final_tension_n"] >= MID_RAMP_N / 2, truth["final_tension_n"]


def test_a_bus_quiet_for_a_second_mid_ramp_costs_a_repeated_trial(tmp_path, hardware_twin):
    twin, run = _start(tmp_path, hardware_twin, patience_s=5.0)
    # Longer than the servos' Bus Watchdog (0.5 s): it trips while the adapter hangs.
    twin.say("freeze servos 1", "freeze servos")
    out, _ = run.communicate(timeout=180)
    report = json.loads(out)
    notes = _notes(tmp_path)
    _assert_repeated_to_its_slip(report, run.returncode, notes)
    # Repeated (a host stalled beyond the watchdog by a loaded machine may void it once more).
    assert _journal(tmp_path)["retried_trials"][:1] == [1], "\n".join(n for n in notes if "late by" not in n)
    assert any("Bus Watchdog tripped" in n for n in notes), notes
    assert_released(twin.stop())


def test_a_host_paused_mid_ramp_finds_the_tripped_watchdog_clears_it_and_repeats_the_trial(
    tmp_path, hardware_twin
):
    twin, run = _start(tmp_path, hardware_twin, patience_s=5.0)
    run.send_signal(signal.SIGSTOP)  # the host stops (a suspend, a slow disk); the servos' watchdog trips
    try:
        time.sleep(1.0)  # twice the servos' Bus Watchdog (500 ms)
    finally:
        run.send_signal(signal.SIGCONT)
    out, _ = run.communicate(timeout=180)
    report = json.loads(out)
    notes = _notes(tmp_path)
    _assert_repeated_to_its_slip(report, run.returncode, notes)
    assert any("servo 1 (winch): Bus Watchdog tripped" in n and "cleared and re-armed" in n for n in notes)
    assert any(n.startswith("control tick late by") for n in notes)
    assert _journal(tmp_path)["retried_trials"][:1] == [1]
    assert_released(twin.stop())


def test_a_bus_silent_beyond_the_patience_ends_the_run_saying_what_state_the_winch_is_in(
    tmp_path, hardware_twin
):
    twin, run = _start(tmp_path, hardware_twin, patience_s=1.0)
    twin.say("freeze servos", "freeze servos")
    out, _ = run.communicate(timeout=180)  # the run gives up while the bus is still frozen
    report = json.loads(out)
    assert run.returncode == 1
    assert report["safe_state_verified"] is False
    reason = report["reason"]
    assert f"the winch has not answered on the servo bus {twin.servo_link}" in reason
    assert "servos.release_patience_s 1 s" in reason
    assert "their Bus Watchdog holds the winch where it was, torque on" in reason
    assert "THE LINE MAY BE LOADED" in reason
    _assert_held_loaded(twin)


def test_a_servo_adapter_pulled_out_is_reported_naming_its_port(tmp_path, hardware_twin):
    twin, run = _start(tmp_path, hardware_twin, patience_s=5.0)
    twin.say("unplug servos", "unplug servos")  # the pty's other end is gone: EIO, as a pulled adapter
    out, _ = run.communicate(timeout=180)
    report = json.loads(out)
    assert run.returncode == 1
    reason = report["reason"]
    assert "internal error" not in reason and "error(5" not in reason
    assert f"servo port {twin.servo_link} vanished" in reason
    assert "was unplugged or lost power" in reason and "--resume" in reason
    assert report["safe_state_verified"] is False and "THE LINE MAY BE LOADED" in reason
    _assert_held_loaded(twin)
