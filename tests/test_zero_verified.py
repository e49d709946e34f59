"""Zero verified: a run never takes a loaded line as zero, and a tare beyond the tolerance is an interlock.

At connect the load cell must read within `limits.zero_tolerance_n` of its calibrated zero before
anything moves; otherwise the run stops (exit 1) with the reading and what to do, the winch pays line
out (never in) and torque goes off. A trial's tare beyond the same tolerance stops the run as an
interlock rather than being subtracted. Every case reads the simulated world at the end: the line
slack and every servo's torque off.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.errors import ConfigError
from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunReport, RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.sim.settings import load_checked_rig_config, require_simulated
from rig.sim.simulated_rig import SimulatedRig, config_preset

ROOT = Path(__file__).resolve().parent.parent
SMOKE = ROOT / "protocols" / "smoke.yaml"
SLACK_N = 0.5


def _rig(tmp_path: Path, simulation: str, limits: str = "") -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(
        f"extends: simulated\nname: zero-test\nsimulation:\n{simulation}"
        + (f"limits:\n{limits}" if limits else ""),
        encoding="utf-8",
    )
    return path


def _run(rig: Path, out: Path) -> tuple[RunReport, SimulatedRig, float]:
    prepared = prepare_run(RunRequest(SMOKE, rig, out, seed=0, run_id="zero"))
    sim = open_simulated_rig(prepared)
    start_rad = sim.devices.bus.servo(1).present_position_rad
    report = execute_run(prepared, sim, SilentProgress())
    return report, sim, start_rad


def _assert_slack_and_off(sim: SimulatedRig) -> None:
    world, bus = sim.devices.world, sim.devices.bus
    assert world.tension_n < SLACK_N, world.tension_n
    assert not any(servo.torque_enabled for servo in bus.servos)


def _winch_goals(out: Path) -> list[float]:
    commands = read_run(out).topic("/rig/servo/command")
    goals = commands[(commands.servo_id == 1) & (commands.command == "goal_position")]
    return list(goals.value)


def test_the_simulated_line_can_start_loaded(tmp_path):
    config = load_rig_config(_rig(tmp_path, "  initial_tension_n: 30\n"))
    assert require_simulated(config).initial_tension_n == 30.0
    preset = config_preset(config, 0)
    # Stretched by 30 N / 5000 N/m = 6 mm of line, 0.6 rad of a 10 mm drum.
    assert preset.winch_slack_rad == pytest.approx(-0.6)
    with pytest.raises(ConfigError, match=r"simulation\.initial_tension_n"):
        load_checked_rig_config(_rig(tmp_path, "  initial_tension_n: -1\n"))


@pytest.mark.parametrize("tension_n", [30.0, 150.0])
def test_a_line_loaded_at_connect_is_refused_and_left_slack(tmp_path, tension_n):
    report, sim, start_rad = _run(_rig(tmp_path, f"  initial_tension_n: {tension_n}\n"), tmp_path / "out")
    assert report.exit_code == 1 and report.completed == 0
    reason = report.reason or ""
    assert reason.startswith("ZeroNotVerified: the load cell reads +") and "at connect" in reason
    assert "limits.zero_tolerance_n (2 N)" in reason and "in small steps, the tension falling" in reason
    assert "if the line is slack now, start the run again" in reason
    assert report.safe_state_verified  # the winch holds where the cell read the line slack
    _assert_slack_and_off(sim)
    # It only paid line out (reeling in is positive), in small steps: the winch ends below where it
    # started, and every goal it was given lies between there and where it ends.
    end_rad = sim.devices.bus.servo(1).present_position_rad
    assert end_rad < start_rad
    goals = _winch_goals(tmp_path / "out")
    assert len(goals) >= 3 and all(end_rad - 0.03 <= g <= start_rad for g in goals)
    assert max(abs(b - a) for a, b in zip([start_rad, *goals], goals, strict=False)) < 0.05
    # No trial ran: the world saw only the loading it started with.
    assert report.completed == 0 and len(sim.devices.world.trials) == 1


def test_a_loaded_line_within_a_wider_tolerance_is_taken(tmp_path):
    # The control: the same start passes when the tolerance covers the reading (so the refusal above
    # is the tolerance's doing, not something else about a loaded start).
    report, _sim, _ = _run(
        _rig(tmp_path, "  initial_tension_n: 30\n", "  zero_tolerance_n: 50\n"), tmp_path / "out"
    )
    assert "ZeroNotVerified" not in (report.reason or "")


def test_a_tare_beyond_the_tolerance_is_an_interlock(tmp_path):
    # A load cell whose zero drifts 0.5 N/s: trial 1's tare (about 1 s in) is within 2 N, trial 2's is not.
    report, sim, _ = _run(_rig(tmp_path, "  loadcell: {drift_n_per_s: 0.5}\n"), tmp_path / "out")
    assert report.exit_code == 1 and report.completed == 1, report.reason
    reason = report.reason or ""
    assert (
        reason.startswith("InterlockTripped: trial 2: tare +") and "limits.zero_tolerance_n (2 N)" in reason
    )
    # The line is slack, but the drifted cell cannot say so: "safe" is what the sensors confirm.
    assert not report.safe_state_verified
    assert "the load cell reads +" in reason and "with the winch at its zero-tension angle" in reason
    _assert_slack_and_off(sim)


def test_the_default_tolerance_lets_every_shipped_tare_through(tmp_path):
    # Without drift the same rig completes: the interlock above is the drift's doing.
    report, sim, _ = _run(_rig(tmp_path, "  loadcell: {drift_n_per_s: 0.0}\n"), tmp_path / "out")
    assert report.exit_code == 0, report.reason
    assert all(abs(t.tare_n) <= 2.0 for t in report.trials)
    _assert_slack_and_off(sim)


def test_a_loaded_line_on_a_reversed_winch_is_paid_out_the_way_the_cell_confirms(tmp_path):
    # The drum is wound the other way and the config does not know it: the first small step "out"
    # reels in. The cell sees the rise; the winch goes back and pays out the other way instead,
    # step by step, and the run stops saying that reel_direction is probably wrong.
    # 10 N: below the first trial's slip load, so the link holds while the winch steps.
    rig = _rig(tmp_path, "  initial_tension_n: 10\n  winch_reversed: true\n")
    report, sim, start_rad = _run(rig, tmp_path / "out")
    assert report.exit_code == 1 and report.completed == 0
    reason = report.reason or ""
    assert "reel_direction is probably wrong" in reason and "--move --write" in reason
    assert report.safe_state_verified
    _assert_slack_and_off(sim)
    # With the config's reel_direction +1, paying out lowers the position; on this reversed drum that
    # reels in. It reeled in by one small step at most and ended paying out the other way (above).
    goals = _winch_goals(tmp_path / "out")
    assert start_rad - min(goals) < 0.05
    assert sim.devices.bus.servo(1).present_position_rad > start_rad


def test_a_cell_lost_in_the_middle_of_the_payout_leaves_the_winch_where_it_read_lowest(tmp_path):
    # The cell's port fails 0.5 s in, while the loaded line is being paid out step by step. The safe
    # state must not wind the winch back to where the line was loaded at connect (before: the zero
    # stayed there, and the line ended at 5.3 N again); it goes to the step the cell read lowest,
    # and the reason says that the tension was not measured at the end.
    rig = _rig(
        tmp_path,
        "  initial_tension_n: 10\n  faults:\n    - {device: loadcell, kind: disconnect, at_s: 0.5}\n",
    )
    report, sim, start_rad = _run(rig, tmp_path / "out")
    assert report.exit_code == 1 and (report.reason or "").startswith("NotConnectedError: load cell")
    assert "the tension was not measured" in (report.reason or "")
    end_rad = sim.devices.bus.servo(1).present_position_rad
    assert end_rad < start_rad - 0.03  # paid out, and left there
    assert sim.devices.world.tension_n < 3.0  # 5.3 N when the winch went back to its start
    assert not any(servo.torque_enabled for servo in sim.devices.bus.servos)
