"""The ramp against the servo's position resolution at low load-cell rates (issue 21, ramp_speed.py).

One count of the winch is q = line stiffness x spool radius x 2π/4096 of tension (77 mN on the
simulated rig): a stepped ramp reads the slip load no finer than that, so it does not go slower than
one count per sample period below the expected slip load, steps right after a sample, and never
turns back between steps.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from rig.analysis.runlog import read_parts, run_settings
from rig.cli import main
from rig.hw.dxl.units import RAD_PER_PULSE, RAD_S_PER_VELOCITY_UNIT
from rig.log.format import schemas
from rig.runner.ramp_speed import SAMPLING_ERROR_FRACTION, RampSpeeds
from tests.helpers import write_joint_1_protocol

SIM_N_PER_RAD = 50.0  # the built-in simulated rig: 5000 N/m line on a 10 mm spool


def _speeds(rate_hz: float, n_per_rad: float = SIM_N_PER_RAD) -> RampSpeeds:
    return RampSpeeds(fast_rad_s=1.0, slow_rad_s=0.08, rate_hz=rate_hz, n_per_rad=n_per_rad)


def test_one_count_is_77_mN_on_the_simulated_rig_and_3_mN_on_the_templates_line() -> None:
    assert _speeds(10.0).count_n == pytest.approx(0.0767, abs=1e-4)
    assert _speeds(10.0, 200.0 * 0.010).count_n == pytest.approx(0.00307, abs=1e-5)


def test_the_count_floor_is_one_count_per_sample_only_where_that_is_a_stepped_speed() -> None:
    assert _speeds(10.0).count_floor_rad_s == pytest.approx(10 * RAD_PER_PULSE)
    # At 80/s one count per sample is 0.12 rad/s, a profile speed: no floor (the profile is smooth).
    assert 80 * RAD_PER_PULSE > RAD_S_PER_VELOCITY_UNIT and _speeds(80.0).count_floor_rad_s == 0.0
    slow = _speeds(10.0)
    # 6 N at 10/s: the limit is 0.0056 rad/s (28 mN a sample), under one count a sample (77 mN).
    assert slow.slow_at(6.0, 2.0) == pytest.approx(slow.limit_rad_s(6.0))
    assert slow.slow_at(6.0, 2.0, counted=True) == pytest.approx(10 * RAD_PER_PULSE)
    # From 16.3 N on the limit is above the floor and the floor changes nothing.
    assert (
        slow.slow_at(20.0, 2.0, counted=True)
        == slow.slow_at(20.0, 2.0)
        == pytest.approx(slow.limit_rad_s(20.0))
    )
    assert _speeds(1000.0).slow_at(2.0, 2.0, counted=True) == 0.08  # 1 kHz: the protocol's speed


@pytest.mark.parametrize("counted", [False, True])
@pytest.mark.parametrize("rate_hz", [10.0, 80.0, 1000.0])
def test_slow_ramp_time_with_the_floor_is_the_integral_of_the_speed(rate_hz: float, counted: bool) -> None:
    speeds = _speeds(rate_hz)
    forces = np.linspace(2.0, 70.0, 400_001)
    per_n = 1.0 / (np.array([speeds.slow_at(f, 2.0, counted=counted) for f in forces]) * SIM_N_PER_RAD)
    numeric = float(np.sum((per_n[1:] + per_n[:-1]) / 2.0 * np.diff(forces)))
    assert speeds.slow_ramp_s(2.0, 70.0, counted=counted) == pytest.approx(numeric, rel=1e-4)
    if counted and rate_hz == 10.0:  # the floor saves time at 10/s: 2-16 N in 18 s instead of 44 s
        assert speeds.slow_ramp_s(2.0, 16.0, counted=True) < 0.5 * speeds.slow_ramp_s(2.0, 16.0)


def test_a_10_per_s_run_steps_whole_counts_after_samples_and_reads_slips_within_a_count(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text("extends: simulated\nsimulation: {loadcell_rate_hz: 10}\n")
    protocol = write_joint_1_protocol(
        tmp_path / "p.yaml",
        "slow",
        {"fast_speed_rad_s": 1.0, "slow_speed_rad_s": 0.08, "max_force_n": 70.0},
        [0.25, 0.22, 0.25, 0.19],
    )
    argv = ["run", str(protocol), "--rig", str(rig), "--seed", "0", "--json", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert [t["outcome"] for t in report["trials"]] == ["slip"] * 4
    parts = read_parts(report["log"])
    part = parts[0].log
    samples_ns = part.topic(schemas.LOADCELL)["log_time_ns"].to_numpy()
    phases = part.topic(schemas.TRIAL_STATE)
    commands = part.topic(schemas.SERVO_COMMAND)
    goals = commands[(commands["role"] == "winch") & (commands["command"] == "goal_position")]
    slow_starts = phases[phases["phase"] == "ramp_slow"]["log_time_ns"].to_numpy()
    ends = phases[phases["phase"] == "unloading"]["log_time_ns"].to_numpy()
    stepped_writes, all_steps = 0, 0
    for start, end in zip(slow_starts, ends, strict=True):
        ramp = goals[(goals["log_time_ns"] >= start) & (goals["log_time_ns"] < end)]
        times, counts = ramp["log_time_ns"].to_numpy()[:-1], ramp["value"].to_numpy()[:-1] / RAD_PER_PULSE
        steps = np.diff(counts)  # (the last write, the hold after the slip, left out)
        assert np.all(steps >= -1e-6), "a stepped goal went back"
        # A step is a whole number of counts (a speed change may write a fraction), written after a
        # sample that came since the step before: every plateau is sampled.
        whole = np.isclose(steps, np.round(steps), atol=1e-6) & (steps > 0.5)
        all_steps += len(steps)
        for earlier, later in zip(times[:-1][whole], times[1:][whole], strict=True):
            assert np.any((samples_ns > earlier) & (samples_ns <= later)), "two steps with no sample"
            stepped_writes += 1
    assert stepped_writes > 20 and stepped_writes > 0.6 * all_steps  # fractional goals before: about 0
    # Every slip load is read within one count (or the sampling limit) of the truth, and the noise.
    world = run_settings(parts, []).truth
    assert world is not None
    count_n = _speeds(10.0).count_n
    for trial, truth in zip(report["trials"], world["world"]["trials"], strict=True):
        load_n = truth["slip_events"][0]["load_n"]
        allowed_n = max(SAMPLING_ERROR_FRACTION * load_n, count_n) + 3 * 0.005
        assert load_n - allowed_n <= trial["peak_force_n"] <= load_n + 3 * 0.005
        assert math.isfinite(trial["peak_force_n"])


def test_on_the_compliant_10_per_s_scenario_slip_loads_are_read_within_half_a_percent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = Path(__file__).resolve().parent.parent / "protocols" / "rigs" / "scenarios" / "compliant-10.yaml"
    protocol = write_joint_1_protocol(
        tmp_path / "p.yaml",
        "soft",
        {"fast_speed_rad_s": 4.0, "slow_speed_rad_s": 0.48, "max_force_n": 70.0, "unload_speed_rad_s": 4.0},
        [0.25, 0.22, 0.25, 0.19],
    )
    argv = ["run", str(protocol), "--rig", str(rig), "--seed", "0", "--json", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert [t["outcome"] for t in report["trials"]] == ["slip"] * 4
    world = run_settings(read_parts(report["log"]), []).truth
    assert world is not None
    # One count is 12.8 mN here (833 N/m), 0.2 % of these 6-9 N slips: the stiff line's 77 mN was 1.3 %
    # (this protocol at 10/s on the stiff line, seed 0: trial 3 read 0.89 % low).
    assert _speeds(10.0, 833.0 * 0.01).count_n == pytest.approx(0.0128, abs=1e-4)
    for trial, truth in zip(report["trials"], world["world"]["trials"], strict=True):
        load_n = truth["slip_events"][0]["load_n"]
        assert abs(trial["peak_force_n"] / load_n - 1.0) < 0.005
