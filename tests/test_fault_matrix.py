"""The fault matrix: every scenario config under protocols/rigs/faults/ ends as the README's table says.

Each scenario runs the smoke protocol on the simulated rig with its faults; the simulator's truth
says what a person at the rig would find afterwards: the line's tension and whether any servo
still has torque. Where the servos can hear the host, the line must end slack.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]
FAULTS = ROOT / "protocols" / "rigs" / "faults"
SLACK_N = 0.5


@dataclass(frozen=True)
class Expected:
    exit_code: int
    completed: int | None  # trials done (None: any)
    slack: bool  # the line ends slack (true tension below SLACK_N)
    torque_off: bool
    verified: bool  # the run reports the safe state as verified
    reason: str = ""  # a fragment of the reason
    retries: int = 0  # trials repeated after a device fault that cleared


MATRIX = {
    "flaky-bus": Expected(0, 2, slack=True, torque_off=True, verified=True),
    "flaky-loadcell": Expected(0, 2, slack=True, torque_off=True, verified=True),
    "loadcell-unplugged": Expected(
        1, 0, slack=True, torque_off=True, verified=True, reason="NotConnectedError"
    ),
    "winch-overload": Expected(0, 2, slack=True, torque_off=True, verified=True, retries=1),
    "loadcell-gap": Expected(0, 2, slack=True, torque_off=True, verified=True, retries=1),
    "winch-silent": Expected(1, 0, slack=True, torque_off=True, verified=False, reason="LINE MAY BE LOADED"),
    "winch-disconnected": Expected(
        1, 0, slack=False, torque_off=False, verified=False, reason="LINE MAY BE LOADED"
    ),
    "disk-full": Expected(1, None, slack=True, torque_off=True, verified=True, reason="LogWriteError"),
    "reversed-winch": Expected(
        1, 0, slack=True, torque_off=True, verified=True, reason="WinchDirectionError: trial 1: the winch"
    ),
    "loaded-at-connect": Expected(
        1, 0, slack=True, torque_off=True, verified=True, reason="ZeroNotVerified: the load cell reads"
    ),
    # The line is slack, but the drifted cell reads it loaded: not verified (the sensors decide).
    "drifting-zero": Expected(1, 1, slack=True, torque_off=True, verified=False, reason="trial 2: tare"),
    "host-pause": Expected(0, 2, slack=True, torque_off=True, verified=True, retries=1),
}


def test_every_scenario_config_is_in_the_matrix():
    assert sorted(p.stem for p in FAULTS.glob("*.yaml")) == sorted(MATRIX)


@pytest.mark.slow
@pytest.mark.parametrize("scenario", sorted(MATRIX))
def test_fault_scenario_ends_as_stated(scenario, tmp_path):
    expected = MATRIX[scenario]
    request = RunRequest(
        protocol_path=ROOT / "protocols" / "smoke.yaml",
        rig_path=FAULTS / f"{scenario}.yaml",
        out_dir=tmp_path,
        seed=0,
        run_id=scenario,
    )
    prepared = prepare_run(request)
    sim = open_simulated_rig(prepared)
    report = execute_run(prepared, sim, SilentProgress())
    assert report.exit_code == expected.exit_code, report.reason
    if expected.completed is not None:
        assert report.completed == expected.completed
    assert expected.reason in (report.reason or "")
    assert report.safe_state_verified == expected.verified, report.reason
    truth = report.truth
    assert truth is not None
    assert (truth.final_tension_n < SLACK_N) == expected.slack, truth.final_tension_n
    assert truth.torque_off == expected.torque_off
    journal = prepared.journal
    assert len(journal.retried_trials) == expected.retries
    fired = sim.devices.faults.fired
    assert all(f.startswith(("servos", "winch", "bender", "loadcell", "host")) for f in fired)
