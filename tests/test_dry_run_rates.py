"""`rig run --dry-run`'s duration estimate at low load-cell rates (issue 21): the ramp timed as it runs.

The ramp's rate cap (rig/runner/ramp_speed.py) slows the ramp at 10/s; the dry run's estimate uses
the same definition (`RampSpeeds.planned_ramp_s`). It assumes every slip at half the ramp's maximum
force, so it is off the simulated run time (first trial's start to last trial's end) by what the
protocol's slips are off that: measured in benchmarks/README.md ("The dry run's estimate").
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from rig.inputs.protocol import load_protocol
from rig.inputs.rig_config import load_rig_config
from rig.runner.limits import estimated_trial_s, ramp_speeds
from rig.runner.ramp_speed import RampSpeeds
from tests.helpers import write_joint_1_protocol

REPO = Path(__file__).resolve().parent.parent


def _protocol(tmp_path: Path) -> Path:
    """Four distances on joint 1, twice each, on the shipped joint-estimation ramp speeds."""
    ramp = {"fast_speed_rad_s": 1.0, "slow_speed_rad_s": 0.08, "max_force_n": 70.0}
    return write_joint_1_protocol(tmp_path / "p.yaml", "six", ramp, [0.03, 0.0614, 0.1243, 0.25], repeats=2)


def _rig(tmp_path: Path, rate_hz: float) -> Path:
    rig = tmp_path / f"rig{rate_hz:g}.yaml"
    rig.write_text(f"extends: simulated\nsimulation: {{loadcell_rate_hz: {rate_hz:g}}}\n")
    return rig


def test_the_estimate_times_the_ramp_with_the_runs_speeds(tmp_path: Path) -> None:
    plan = load_protocol(_protocol(tmp_path))
    slow, fast = load_rig_config(_rig(tmp_path, 10.0)), load_rig_config(None)
    assert ramp_speeds(plan, slow) == RampSpeeds(1.0, 0.08, 10.0, 50.0)
    trial = plan.trials[1]
    # At 1 kHz the limit never binds: the fast phase to 70 % of 35 N, then 0.08 rad/s (4 N/s).
    later_1k = estimated_trial_s(trial, plan, fast, 35.0)
    first_1k = estimated_trial_s(trial, plan, fast, 35.0, first=True)
    assert first_1k - later_1k == pytest.approx((35.0 - 2.0) / 4.0 - (24.5 / 50.0 + 10.5 / 4.0 - 2.0 / 50.0))
    # At 10/s the same trial takes longer, the first (slow from the arm threshold) longest.
    later_10 = estimated_trial_s(trial, plan, slow, 35.0)
    first_10 = estimated_trial_s(trial, plan, slow, 35.0, first=True)
    assert later_10 > later_1k + 2.0 and first_10 > later_10 + 20.0


def test_a_dry_run_estimates_the_simulated_run_time_within_a_factor_of_2_and_the_slowdown_at_10_per_s(
    tmp_path: Path, cli_json: Callable[..., Any]
) -> None:
    protocol = _protocol(tmp_path)
    estimated, measured = {}, {}
    for rate_hz in (10.0, 1000.0):
        rig = _rig(tmp_path, rate_hz)
        plan = cli_json("run", protocol, "--rig", rig, "--dry-run", "--json")
        assert f"{rate_hz:g} samples/s" in plan["duration_assumption"]
        out = tmp_path / f"o{rate_hz:g}"
        trials = cli_json("run", protocol, "--rig", rig, "--seed", "0", "--json", "--out", out)["trials"]
        assert [t["outcome"] for t in trials] == ["slip"] * 8
        estimated[rate_hz] = plan["estimated_duration_s"]
        measured[rate_hz] = (trials[-1]["end_time_ns"] - trials[0]["start_time_ns"]) / 1e9
        # 2026-11-27, seed 0: 98.3 s for 99.5 s at 10/s, 36.9 s for 44.1 s at 1000/s.
        assert 0.5 * measured[rate_hz] <= estimated[rate_hz] <= 2.0 * measured[rate_hz]
    # The slowdown at 10/s, estimated (2.66x) against measured (2.26x); 1.0x before the estimate
    # knew of the rate cap.
    slowdown = estimated[10.0] / estimated[1000.0]
    assert slowdown == pytest.approx(measured[10.0] / measured[1000.0], rel=0.3)


def test_a_dry_run_at_10_per_s_estimates_longer_than_at_1khz(cli_json: Callable[..., Any]) -> None:
    default = cli_json("run", REPO / "protocols" / "joint_estimation.yaml", "--dry-run", "--json")
    scenario = REPO / "protocols" / "rigs" / "scenarios" / "cell-hx711-10.yaml"
    slow = cli_json(
        "run", REPO / "protocols" / "joint_estimation.yaml", "--rig", scenario, "--dry-run", "--json"
    )
    # 258 s against 117 s (2026-11-27): the 10/s ramp is capped below 85 N, the first trial from 2 N.
    assert slow["estimated_duration_s"] > 1.8 * default["estimated_duration_s"]
    # One winch count of the 5000 N/m line on the 10 mm drum: the slip load's resolution.
    assert default["slip_load_resolution_n"] == pytest.approx(5000 * 0.01 * 2 * 3.141592653589793 / 4096)
