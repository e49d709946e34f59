"""The simulated configuration source: noise statistics, slipped-joint reports, out-of-plane readings."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from model.chain import planar_transforms
from rig.hw.seams import ConfigurationSource
from rig.sim.physics.configuration_source import SimConfigurationSource
from rig.sim.physics.link_presets import make_preset
from rig.sim.physics.world import SimWorld
from rig.sim.virtual_clock import VirtualClock
from tests.helpers import ScriptedShaft, set_up_trial

MS = 1_000_000


def test_planar_readings_have_the_configured_noise() -> None:
    preset = replace(make_preset("link1", seed=3), sigma_meas_rad=math.radians(0.5))
    clock = VirtualClock()
    world = SimWorld(preset, ScriptedShaft(), seed=3)
    clock.on_advance(world.advance_to)
    truth = np.array([0.2, -0.1, 0.0, 0.3, -0.25, 0.1, 0.05, -0.05])
    world.set_configuration(truth)
    source = SimConfigurationSource(world, clock)
    assert isinstance(source, ConfigurationSource)
    clock.advance_ns(5 * MS)
    readings = [source.measure() for _ in range(2000)]
    assert readings[0].time_ns == clock.time_ns()
    errors = np.array([r.joint_angles_rad for r in readings]) - truth
    sigma = math.radians(0.5)
    assert errors.std() == pytest.approx(sigma, rel=0.03)
    assert np.abs(errors.mean(axis=0)).max() < 5 * sigma / math.sqrt(2000)
    reading = readings[7]
    assert np.allclose(reading.transforms, planar_transforms(np.array(reading.joint_angles_rad), 0.03))
    assert all(r.slipped_joint is None for r in readings)  # nothing slipped
    # The world's own configuration is untouched by measuring.
    assert np.allclose(world.link.planar_joint_angles(), truth)


def slip_report_fractions(probability: float, seed: int) -> tuple[int, int, bool]:
    """Cycles of (straighten, new trial, reel in to just past the slip load, measure).

    Returns (cycles that slipped, reports, every report named the right joint and none came unasked).
    """
    preset = replace(make_preset("link1", seed=seed), slipped_joint_report_probability=probability)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=seed)
    source = SimConfigurationSource(world)
    seen = reported = 0
    correct = True
    for cycle in range(300):
        world.set_configuration([0.0] * 8)
        trial = set_up_trial(world, "link_validation")
        slips_before = len(world.slips)
        if cycle % 5 == 4:  # now and then a cycle without a slip
            shaft.present_position_rad = world.taut_winch_angle_rad()
        else:
            shaft.present_position_rad = world.line.winch_angle_for_tension_rad(
                trial.slip_force_n * 1.01, world.article.take_up_m
            )
        world.advance_to(world.now_ns + 50 * MS)
        reading = source.measure()
        if len(world.slips) > slips_before:
            seen += 1
            if reading.slipped_joint is not None:
                reported += 1
                correct &= reading.slipped_joint == world.slips[-1].onset.joint
        else:
            correct &= reading.slipped_joint is None
    return seen, reported, correct


def test_the_link_joint_that_moved_is_seen_from_the_configuration_before_and_after() -> None:
    # The report probability is the specimen's: on the link the simulator sees every slip.
    for probability in (0.0, 1.0):
        seen, reported, correct = slip_report_fractions(probability, seed=2)
        assert seen == 240 and reported == seen and correct


def test_the_specimen_slip_is_reported_with_the_configured_probability() -> None:
    preset = replace(make_preset("link1", seed=1), slipped_joint_report_probability=0.5)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=1)
    source = SimConfigurationSource(world)
    seen = reported = 0
    for cycle in range(200):
        trial = set_up_trial(world, "joint_estimation", distance_m=0.1, joint=1 + cycle % 8)
        shaft.present_position_rad = world.line.winch_angle_for_tension_rad(
            trial.slip_force_n * 1.01, world.article.take_up_m
        )
        before = len(world.slips)
        world.advance_to(world.now_ns + 50 * MS)
        reading = source.measure()
        if len(world.slips) > before:
            seen += 1
            if reading.slipped_joint is not None:
                reported += 1
                assert reading.slipped_joint == trial.specimen_joint
        shaft.present_position_rad = 0.0
        world.advance_to(world.now_ns + 50 * MS)
    assert seen >= 150
    assert reported / seen == pytest.approx(0.5, abs=0.12)


def rotation_angle(r: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0)))


def test_out_of_plane_configuration_is_reported_as_noisy_transforms() -> None:
    preset = replace(make_preset("link1", seed=4), sigma_meas_rad=0.01)
    shaft = ScriptedShaft()
    world = SimWorld(preset, shaft, seed=4)
    world.set_configuration([0.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0])
    set_up_trial(world, "link_validation")
    shaft.present_position_rad = world.taut_winch_angle_rad()
    world.step_devices = lambda t_ns: setattr(
        shaft, "present_position_rad", shaft.present_position_rad + 0.002
    )
    world.advance_to(3000 * MS)
    assert world.slips
    true_transforms = world.article.transforms
    assert world.article.planar_joint_angles() is None  # an out-of-plane load drooped the link
    source = SimConfigurationSource(world)
    angles = []
    for _ in range(300):
        reading = source.measure()
        assert reading.joint_angles_rad is None
        assert np.allclose(reading.transforms[:, :3, 3], true_transforms[:, :3, 3])
        for measured, true in zip(reading.transforms, true_transforms, strict=True):
            angles.append(rotation_angle(true[:3, :3].T @ measured[:3, :3]))
    # The rotation-vector error is N(0, σ² I₃): its rms angle is σ·√3.
    assert math.sqrt(np.mean(np.square(angles))) == pytest.approx(0.01 * math.sqrt(3), rel=0.05)


def test_specimen_readings_and_seeded_repeatability() -> None:
    preset = make_preset("link2", seed=6)
    world = SimWorld(preset, ScriptedShaft(), seed=6)
    set_up_trial(world, "joint_estimation", distance_m=0.1)
    a = SimConfigurationSource(world).measure()
    b = SimConfigurationSource(world).measure()
    c = SimConfigurationSource(world, seed=7).measure()
    # The specimen is not the link: no link angles, only its (noisy) pose, seeded.
    assert a.transforms.shape == (1, 4, 4) and a.joint_angles_rad is None
    assert np.array_equal(a.transforms, b.transforms) and not np.array_equal(a.transforms, c.transforms)
    assert a.time_ns == world.now_ns
