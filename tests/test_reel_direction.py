"""Reel direction as configuration: `reel_direction: -1` reels a drum wound the other way correctly.

The simulated world can be wound the other way (`simulation.winch_reversed: true`: reeling in lowers
the winch's position). With `reel_direction: -1` a run on it must give exactly the results of the
default rig, the winch turning the mirror way; with the default direction it never loads the line.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from rig.errors import ConfigError
from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunReport, RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.sim.simulated_rig import SimulatedRig

ROOT = Path(__file__).resolve().parent.parent
SMOKE = ROOT / "protocols" / "smoke.yaml"


def _rig(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text("extends: simulated\nname: reel\n" + body, encoding="utf-8")
    return path


def _run(rig: Path | None, out: Path) -> tuple[RunReport, SimulatedRig]:
    prepared = prepare_run(RunRequest(SMOKE, rig, out, seed=0, run_id="reel"))
    sim = open_simulated_rig(prepared)
    return execute_run(prepared, sim, SilentProgress()), sim


def _winch_positions(out: Path) -> list[float]:
    states = read_run(out).topic("/rig/servo/state")
    return list(states[states.role == "winch"].position_rad)


@pytest.mark.parametrize("value", ["0", "2", "1.5", "backwards"])
def test_only_plus_or_minus_one_is_a_direction(tmp_path, value):
    with pytest.raises(ConfigError, match=r"rig\.yaml: reel_direction: .*allowed"):
        load_rig_config(_rig(tmp_path, f"reel_direction: {value}\n"))
    assert load_rig_config(_rig(tmp_path, "reel_direction: -1\n")).reel_direction == -1
    assert load_rig_config(None).reel_direction == 1


def test_a_reversed_drum_with_direction_minus_one_mirrors_the_default_run(tmp_path):
    default, default_sim = _run(None, tmp_path / "default")
    mirrored, mirrored_sim = _run(
        _rig(tmp_path, "reel_direction: -1\nsimulation:\n  winch_reversed: true\n"), tmp_path / "mirrored"
    )
    assert default.exit_code == mirrored.exit_code == 0
    assert [t.outcome for t in default.trials] == ["slip", "slip"]
    assert mirrored.trials == default.trials  # every field: forces, masses, tares, times
    assert mirrored.estimate == default.estimate
    # The winch turned the other way: positive from its start on the default rig, negative here.
    plain, mirror = _winch_positions(tmp_path / "default"), _winch_positions(tmp_path / "mirrored")
    assert max(plain) - plain[0] > 0.5 and min(mirror) - mirror[0] < -0.5
    assert max(plain) - plain[0] == pytest.approx(mirror[0] - min(mirror), abs=1e-3)
    for sim in (default_sim, mirrored_sim):
        assert sim.devices.world.tension_n == 0.0
        assert not any(servo.torque_enabled for servo in sim.devices.bus.servos)


def test_a_reversed_drum_with_the_default_direction_stops_within_a_quarter_turn(tmp_path):
    # The control: the setting is what makes the mirrored run work. Wound the other way, the default
    # direction pays line out; the first ramp sees no rise and stops the run (exit 1) once the winch
    # has turned limits.direction_check_rev (0.25 turn), naming the fix. Before, both ramps paid out
    # up to 7.5 turns each until their timeouts, and the run exited 0.
    rig = _rig(tmp_path, "simulation:\n  winch_reversed: true\n")
    report, sim = _run(rig, tmp_path / "out")
    assert report.exit_code == 1 and report.trials == []
    reason = report.reason or ""
    assert reason.startswith("WinchDirectionError: trial 1: the winch reeled in")
    assert "reel_direction (+1)" in reason and f"rig check --rig {rig} --move --write" in reason
    assert report.safe_state_verified
    positions = _winch_positions(tmp_path / "out")
    turned_rev = (max(positions) - positions[0]) / (2 * math.pi)
    assert 0.25 <= turned_rev < 0.3, turned_rev
    assert positions[-1] == pytest.approx(positions[0], abs=0.02)  # back at its zero
    assert sim.devices.world.tension_n == 0.0
    assert not any(servo.torque_enabled for servo in sim.devices.bus.servos)
