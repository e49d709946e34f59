"""The simulated world: line tension, slips against model.chain, stick-slip, trials, truth, history."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model.chain import planar_transforms, predict_slip
from model.joint import PAPER_CONSTANT
from rig.sim.physics.link_presets import PRESET_NAMES, SimPreset, make_preset
from rig.sim.physics.world import SimWorld, TrialKind
from rig.sim.truth import WorldTruth
from tests.helpers import ScriptedShaft, set_up_trial

MS = 1_000_000
S = 1_000_000_000


class Ramp:
    """step_devices callback: the shaft turns at a constant rate from `t0_ns` (ignores the torque)."""

    def __init__(self, shaft: ScriptedShaft, rate_rad_s: float, t0_ns: int = 0, start_rad: float = 0.0):
        self.shaft, self.rate, self.t0_ns, self.start_rad = shaft, rate_rad_s, t0_ns, start_rad

    def __call__(self, t_ns: int) -> None:
        self.shaft.present_position_rad = self.start_rad + self.rate * max(0, t_ns - self.t0_ns) * 1e-9


def strong(preset: SimPreset) -> SimPreset:
    """The preset with joints that never slip in these tests."""
    return replace(preset, joint_capacities_nm=(1e6,) * preset.joint_count, specimen_capacity_nm=1e6)


def test_tension_follows_winch_angle_and_line_stiffness() -> None:
    preset = replace(strong(make_preset("link1", seed=3)), spring_stiffness_n_per_m=1000.0)
    shaft = ScriptedShaft(position_rad=1.0)
    world = SimWorld(preset, shaft)
    slack = 1.0 + preset.winch_slack_rad
    k_eff = 1.0 / (1.0 / preset.line_stiffness_n_per_m + 1.0 / preset.spring_stiffness_n_per_m)
    assert world.line.stiffness_n_per_m == pytest.approx(k_eff)
    for i, angle in enumerate([1.0, slack - 0.01, slack + 0.5, slack + 3.0, slack + 1.0]):
        shaft.present_position_rad = angle
        world.advance_to((i + 1) * 10 * MS)
        expected = max(0.0, k_eff * preset.drum_radius_m * (angle - slack))
        assert world.tension_n == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert shaft.external_torque_nm == pytest.approx(-expected * preset.drum_radius_m)
    assert world.tension_n > 0  # the last angle is taut

    no_spring = replace(preset, spring_stiffness_n_per_m=None)
    shaft2 = ScriptedShaft()
    world2 = SimWorld(no_spring, shaft2)
    shaft2.present_position_rad = no_spring.winch_slack_rad + 0.2
    world2.advance_to(MS)
    assert world2.tension_n == pytest.approx(no_spring.line_stiffness_n_per_m * 0.01 * 0.2)


def ramp_until_first_slip(
    world: SimWorld,
    shaft: ScriptedShaft,
    rate_rad_s: float,
    limit_s: float = 60.0,
    *,
    from_slack: bool = True,
):
    """Reel in at a constant rate from the world's time until the first slip; returns the record.

    With `from_slack`, the winch first goes back to 0.1 rad short of taut.
    """
    start_ns = world.now_ns
    if from_slack:
        shaft.present_position_rad = world.taut_winch_angle_rad() - 0.1
    ramp = Ramp(shaft, rate_rad_s, t0_ns=start_ns, start_rad=shaft.present_position_rad)
    world.step_devices = ramp
    n_before = len(world.slips)
    t = start_ns
    while len(world.slips) == n_before:
        t += 100 * MS
        assert t - start_ns < limit_s * S, "no slip within the time limit"
        world.advance_to(t)
    return world.slips[n_before]


@settings(max_examples=20, deadline=None)
@given(
    angles=st.lists(st.floats(-0.8, 0.8), min_size=8, max_size=8),
    seed=st.integers(0, 10_000),
    in_plane=st.booleans(),
)
def test_first_slip_is_model_predict_slip_on_the_trial_capacities(angles, seed, in_plane) -> None:
    direction = (-1.0, 0.0, 0.0) if in_plane else (0.0, -1.0, 0.0)
    preset = make_preset("link1", seed=seed, direction_w=direction)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=seed)
    world.set_configuration(angles)
    trial = set_up_trial(world, "link_validation")
    transforms = planar_transforms(np.asarray(angles), preset.segment_lengths_m)
    prediction = predict_slip(transforms, trial.capacities_nm, preset.point_m, direction, g=preset.g)
    if not math.isfinite(float(prediction.slip_force_n)) or prediction.slip_force_n > 200:
        return  # the line passes (nearly) through every joint: nothing to ramp to
    assert trial.slip_force_n == pytest.approx(float(prediction.slip_force_n), rel=1e-9)
    assert trial.first_slip_joint == int(prediction.first_slip_joint)
    assert trial.slip_mass_kg == pytest.approx(float(prediction.slip_mass_kg), rel=1e-9)

    rate = 1.0
    record = ramp_until_first_slip(world, shaft, rate)
    assert record.onset.joint == int(prediction.first_slip_joint)
    assert record.onset.threshold_n == pytest.approx(float(prediction.slip_force_n), rel=1e-9)
    ramp_n_per_substep = world.line.stiffness_n_per_m * preset.drum_radius_m * rate * 1e-3
    assert (
        prediction.slip_force_n <= record.onset.peak_tension_n <= prediction.slip_force_n + ramp_n_per_substep
    )
    assert record.onset.trial_index == trial.index


def test_stick_slip_drops_to_the_kinetic_level_then_rises_again() -> None:
    preset = make_preset("link1", seed=11)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=11)
    world.set_configuration([0.3, -0.2, 0.1, 0.0, 0.2, -0.1, 0.0, 0.1])
    set_up_trial(world, "link_validation")
    first = ramp_until_first_slip(world, shaft, 0.5)
    # Reeling on at 0.5 rad/s (25 N/s) the tension regains the ~1.4 N drop in about 55 ms.
    world.advance_to(world.now_ns + 70 * MS)
    assert first.end_ns is not None and first.end_ns >= first.onset.onset_ns
    # The slip relieves the line to about the kinetic ratio of the peak (geometry moves it a little).
    assert first.tension_after_n / first.onset.peak_tension_n == pytest.approx(preset.kinetic_ratio, abs=0.01)
    assert first.rotation_rad > 0
    # The history holds each substep's tension before that substep's slip motion.
    assert world.tension_at(first.onset.onset_ns) == first.onset.peak_tension_n
    ramp_n_per_ms = world.line.stiffness_n_per_m * world.preset.drum_radius_m * 0.5e-3
    after = world.tension_at(first.end_ns + MS)
    assert first.tension_after_n <= after <= first.tension_after_n + ramp_n_per_ms + 1e-12
    # The winch kept reeling: the tension rose again to a second slip near the static level.
    assert len(world.slips) == 2
    second = world.slips[1]
    assert second.onset.onset_ns > first.end_ns
    assert second.onset.peak_tension_n == pytest.approx(first.onset.peak_tension_n, rel=0.02)
    window = np.array([world.tension_at(t) for t in range(first.end_ns + MS, second.onset.onset_ns, MS)])
    assert window.max() <= second.onset.peak_tension_n
    assert np.all(np.diff(window) >= -1e-9)  # sticking: the tension only rises between slips


def test_slip_rate_spreads_the_drop_over_substeps() -> None:
    preset = replace(make_preset("link1", seed=2), slip_rate_rad_s=0.5)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=2)
    set_up_trial(world, "joint_estimation", distance_m=0.1)
    record = ramp_until_first_slip(world, shaft, 1.0)
    world.advance_to(world.now_ns + 2 * S)
    assert record.end_ns is not None
    duration_s = (record.end_ns - record.onset.onset_ns) * 1e-9
    # The drop needs about (1 - kinetic) * f / k_eff of take-up = rotation * l, at 0.5 rad/s.
    assert duration_s == pytest.approx(record.rotation_rad / 0.5, abs=2e-3)
    assert duration_s > 0.01


def test_per_trial_variation_has_the_configured_spread() -> None:
    preset = replace(make_preset("link2", seed=5), per_trial_capacity_sd=0.07)
    world = SimWorld(preset, ScriptedShaft(), seed=5)
    factors = np.array([set_up_trial(world, TrialKind.LINK_VALIDATION).capacity_factors for _ in range(600)])
    assert factors.shape == (600, 10)
    assert factors.mean() == pytest.approx(1.0, abs=0.003)
    assert factors.std() == pytest.approx(0.07, rel=0.04)
    assert factors.min() >= 1 - 3 * 0.07 - 1e-12 and factors.max() <= 1 + 3 * 0.07 + 1e-12
    # Independent between joints.
    correlation = np.corrcoef(factors.T)
    assert np.abs(correlation[np.triu_indices(10, 1)]).max() < 0.15
    trial = world.trials[-1]
    assert np.allclose(trial.capacities_nm, np.array(preset.joint_capacities_nm) * trial.capacity_factors)


def test_joint_estimation_specimen_slips_at_capacity_over_distance() -> None:
    preset = make_preset("link1", seed=8, direction_w=(0.0, -1.0, 0.5))  # the z part cannot act
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=8)
    for distance in (0.05, 0.2):
        trial = set_up_trial(world, "joint_estimation", distance_m=distance)
        assert world.setup == "specimen"
        assert world.article.lever_arms_m()[1] == pytest.approx(distance)
        assert trial.slip_force_n == pytest.approx(trial.capacities_nm[0] / distance)
        assert trial.capacities_nm[0] == pytest.approx(
            preset.specimen_capacity_nm * trial.capacity_factors[0]
        )
        shaft.present_position_rad = 0.0
        world.advance_to(world.now_ns + MS)
        record = ramp_until_first_slip(world, shaft, 2.0)
        assert record.onset.setup == "specimen" and record.onset.joint == 1
        ramp_n_per_substep = world.line.stiffness_n_per_m * preset.drum_radius_m * 2.0 * 1e-3
        assert trial.slip_force_n <= record.onset.peak_tension_n <= trial.slip_force_n + ramp_n_per_substep
    # A named joint of the link as the specimen carries that joint's true capacity.
    trial = set_up_trial(world, "joint_estimation", distance_m=0.1, joint=3)
    assert trial.specimen_joint == 3
    assert trial.capacities_nm[0] == pytest.approx(preset.joint_capacities_nm[2] * trial.capacity_factors[0])
    with pytest.raises(ValueError, match="distance_m"):
        world.place_hook(0.0)
    with pytest.raises(ValueError, match="joint"):
        world.place_hook(0.1, joint=9)


def torsion_world(weak: int | None, direction=(0.0, -1.0, 0.0)) -> tuple[SimWorld, ScriptedShaft]:
    preset = make_preset("link1", seed=0, direction_w=direction, torsion_weak_joint=weak)
    preset = replace(
        preset,
        joint_capacities_nm=(1.6,) * 8,
        per_trial_capacity_sd=0.0,
        torsion_ratio=0.3,
    )
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft)
    # Straight to joint 4, then a right angle: everything distal of joint 4 lies along x.
    world.set_configuration([0.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0])
    return world, shaft


def test_torsion_weak_joint_changes_which_joint_slips_under_an_out_of_plane_load() -> None:
    isotropic, _ = torsion_world(None)
    iso_trial = set_up_trial(isotropic, "link_validation")
    transforms = isotropic.article.transforms
    prediction = predict_slip(transforms, iso_trial.capacities_nm, isotropic.preset.point_m, (0, -1, 0))
    assert iso_trial.first_slip_joint == int(prediction.first_slip_joint) == 1

    weak, shaft = torsion_world(2)
    trial = set_up_trial(weak, "link_validation")
    assert trial.first_slip_joint == 2  # twisted about its own axis by the bent distal part
    assert trial.slip_force_n < iso_trial.slip_force_n
    record = ramp_until_first_slip(weak, shaft, 1.0)
    weak.advance_to(weak.now_ns + 200 * MS)
    assert record.onset.joint == 2
    assert record.onset.threshold_n == pytest.approx(trial.slip_force_n)
    assert weak.article.planar_joint_angles() is None  # it twisted out of the plane
    assert weak.truth().torsion_weak_joint == 2

    # An in-plane load puts no torsion on any joint: the weak joint makes no difference.
    in_plane_iso, _ = torsion_world(None, direction=(-1.0, 0.0, 0.0))
    in_plane_weak, _ = torsion_world(2, direction=(-1.0, 0.0, 0.0))
    a = set_up_trial(in_plane_iso, "link_validation")
    b = set_up_trial(in_plane_weak, "link_validation")
    assert (a.first_slip_joint, a.slip_force_n) == (b.first_slip_joint, pytest.approx(b.slip_force_n))


def test_truth_is_json_serialisable_and_consistent() -> None:
    preset = make_preset("link2", seed=21, torsion_weak_joint=4)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=99)
    set_up_trial(world, "joint_estimation", distance_m=0.1)
    ramp_until_first_slip(world, shaft, 2.0)
    world.advance_to(world.now_ns + 300 * MS)
    truth = json.loads(json.dumps(world.truth().to_json(), allow_nan=False))
    assert truth["seed"] == 99 and truth["article_seed"] == 21 and truth["preset"] == "link2"
    assert len(truth["joints"]) == 10
    joint = truth["joints"][3]
    assert joint["joint"] == 4
    assert joint["capacity_nm"] == pytest.approx(preset.joint_capacities_nm[3])
    assert joint["k_kg_m"] == pytest.approx(preset.joint_capacities_nm[3] / 9.8)
    assert joint["mu_delta0_pa"] == pytest.approx(preset.joint_capacities_nm[3] / (PAPER_CONSTANT * 0.01**3))
    assert truth["constant"] == {"name": "paper", "c": PAPER_CONSTANT}
    assert truth["specimen"]["k_kg_m"] == pytest.approx(0.2627)
    assert truth["noise"]["per_trial_capacity_sd"] == preset.per_trial_capacity_sd
    assert truth["noise"]["sigma_meas_rad"] == preset.sigma_meas_rad
    assert truth["kinetic_ratio"] == preset.kinetic_ratio
    assert truth["torsion"]["torsion_ratio"] == preset.torsion_ratio
    assert truth["trials"][0]["kind"] == "joint_estimation" and truth["trials"][0]["distance_m"] == 0.1
    assert truth["slips"][0]["joint"] == 1 and truth["slips"][0]["peak_tension_n"] > 0


def test_tension_at_interpolates_linearly_within_the_history() -> None:
    preset = strong(make_preset("link1"))
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, history_s=0.5)
    world.step_devices = Ramp(shaft, 2.0, start_rad=preset.winch_slack_rad)
    world.advance_to(1_234_567_891)
    slope_n_per_ns = world.line.stiffness_n_per_m * preset.drum_radius_m * 2.0 * 1e-9
    for t in (900_000_000, 900_500_000, 1_100_123_457, 1_234_567_891):
        assert world.tension_at(t) == pytest.approx(slope_n_per_ns * t, rel=1e-9)
    assert world.tension_at(5 * S) == world.tension_n  # ahead of the world: hold the last value
    with pytest.raises(ValueError, match="older"):
        world.tension_at(100 * MS)
    # A clock advancing in odd steps gives the same history as one long advance.
    other_shaft = ScriptedShaft()
    other = SimWorld(preset, other_shaft, history_s=0.5)
    other.step_devices = Ramp(other_shaft, 2.0, start_rad=preset.winch_slack_rad)
    t = 0
    while t < 1_234_567_891:
        t = min(t + 3_333_333, 1_234_567_891)
        other.advance_to(t)
    assert other.tension_at(1_000_000_000) == pytest.approx(world.tension_at(1_000_000_000), rel=1e-9)


def run_protocol(seed: int) -> WorldTruth:
    preset = make_preset("link1", seed=seed)
    winch = ScriptedShaft()
    world = SimWorld(preset, winch, seed=seed)
    set_up_trial(world, "joint_estimation", distance_m=0.08)
    ramp_until_first_slip(world, winch, 2.0)
    winch.present_position_rad = 0.0
    world.step_devices = None
    set_up_trial(world, "link_validation")
    world.bend_by_hand([0.2] * 8)
    world.advance_to(world.now_ns + 10 * MS)
    ramp_until_first_slip(world, winch, 2.0)
    world.advance_to(world.now_ns + 200 * MS)
    return world.truth()


def test_same_seed_same_world_and_different_seed_different_world() -> None:
    a, b, c = run_protocol(4), run_protocol(4), run_protocol(5)
    assert a == b
    assert a.joints != c.joints
    assert a.trials[0].capacity_factors != c.trials[0].capacity_factors


def test_bending_by_hand_has_the_placement_error_and_a_reset_is_exactly_straight() -> None:
    preset = replace(make_preset("link1", seed=1), sigma_bend_rad=0.02)
    world = SimWorld(preset, ScriptedShaft(), seed=1)
    target = np.array([0.1, -0.2, 0.3, 0.0, 0.1, 0.0, -0.1, 0.2])
    errors = []
    for _ in range(300):
        world.bend_by_hand(target)
        errors.append(np.array(world.link.planar_joint_angles()) - target)
        world.straighten()
        assert world.link.planar_joint_angles() == (0.0,) * 8
    errors_a = np.array(errors)
    assert errors_a.std() == pytest.approx(0.02, rel=0.05)
    assert abs(errors_a.mean()) < 0.002


def test_world_without_forks_refuses_to_engage_one() -> None:
    world = SimWorld(make_preset("link1"), ScriptedShaft())
    with pytest.raises(RuntimeError, match="no fork on component 3"):
        world.engage_fork(3)


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_presets_resemble_the_paper(name: str) -> None:
    preset = make_preset(name, seed=0)
    k = 0.1615 if name == "link1" else 0.2627
    assert preset.specimen_capacity_nm == pytest.approx(k * 9.8)
    capacities = np.array(preset.joint_capacities_nm)
    assert preset.joint_count == (8 if name == "link1" else 10)
    assert abs(capacities.mean() / preset.specimen_capacity_nm - 1) < 0.15
    assert 0.03 < capacities.std() / preset.specimen_capacity_nm < 0.2
    assert make_preset(name, seed=0) == preset
    assert make_preset(name, seed=1).joint_capacities_nm != preset.joint_capacities_nm
    scaled = make_preset(name, seed=0, noise_scale=2.0)
    assert scaled.per_trial_capacity_sd == pytest.approx(2 * preset.per_trial_capacity_sd)
    assert scaled.sigma_meas_rad == pytest.approx(2 * preset.sigma_meas_rad)
    with pytest.raises(ValueError, match="segment lengths"):
        make_preset(name, segment_lengths_m=(0.03, 0.03))
    with pytest.raises(ValueError, match="allowed"):
        make_preset("link3")
