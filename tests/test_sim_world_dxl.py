"""The world coupled to a real emulated winch servo (rig.sim.dxl) in current-based position mode (5)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from rig.hw.dxl import control_table as ct
from rig.sim.dxl.servo import Servo
from rig.sim.physics.link_presets import make_preset
from rig.sim.physics.world import SimWorld
from rig.sim.virtual_clock import VirtualClock
from tests.helpers import set_up_trial

MS = 1_000_000


def write(servo: Servo, address: int, value: int, size: int, now_ns: int) -> None:
    result = servo.write(address, value.to_bytes(size, "little", signed=True), now_ns)
    assert result.error == 0, f"write {address} = {value}: error {result.error}"


def winch_in_mode_5(goal_current_a: float, *, profile_rad_s: float = 1.0) -> Servo:
    """An XM430-W350 winch in current-based position mode, torque on, goal current capped."""
    servo = Servo(ct.table_for_model("XM430-W350"), 1)
    write(servo, ct.ADDR_OPERATING_MODE, 5, 1, 0)
    write(servo, 112, round(profile_rad_s / ct.RAD_S_PER_VELOCITY_UNIT), 4, 0)  # Profile Velocity
    write(servo, ct.ADDR_GOAL_CURRENT, round(goal_current_a / ct.CURRENT_UNIT_A), 2, 0)
    write(servo, ct.ADDR_TORQUE_ENABLE, 1, 1, 0)
    return servo


def reel_to(servo: Servo, angle_rad: float, now_ns: int) -> None:
    write(servo, ct.ADDR_GOAL_POSITION, round(angle_rad / ct.RAD_PER_PULSE), 4, now_ns)


def test_winch_stalls_against_the_line_at_its_goal_current() -> None:
    preset = make_preset("link1", seed=1)
    preset = replace(preset, joint_capacities_nm=(1e6,) * 8)  # nothing slips: a pure stall
    clock = VirtualClock()
    goal_current_a = 0.3
    servo = winch_in_mode_5(goal_current_a, profile_rad_s=3.0)
    world = SimWorld(preset, servo, step_devices=servo.advance_to)
    clock.on_advance(world.advance_to)
    reel_to(servo, 40.0, clock.monotonic_ns())  # far beyond where the line can let it go
    clock.advance_ns(15_000 * MS)
    torque_cap_nm = goal_current_a * servo.motor.torque_constant_nm_per_a
    tension_cap_n = torque_cap_nm / preset.drum_radius_m
    stalled_at = servo.present_position_rad
    assert stalled_at < 40.0 - 1.0  # it never reached its goal
    assert servo.external_torque_nm == pytest.approx(-world.tension_n * preset.drum_radius_m)
    # Stalled: the line holds the motor's capped torque, less at most the gear's friction band.
    band_n = servo.motor.coulomb_nm / preset.drum_radius_m
    assert tension_cap_n - band_n - 1e-6 <= world.tension_n <= tension_cap_n + 1e-6
    clock.advance_ns(1_000 * MS)
    assert servo.present_position_rad == pytest.approx(stalled_at, abs=1e-3)
    assert abs(servo.present_velocity_rad_s) < 1e-3
    # Backing the goal off releases the line (the safe state).
    reel_to(servo, 0.0, clock.monotonic_ns())
    clock.advance_ns(20_000 * MS)
    assert world.tension_n == 0.0
    assert servo.external_torque_nm == 0.0


def test_emulated_winch_drives_stick_slip_at_the_predicted_load() -> None:
    preset = make_preset("link1", seed=3)
    clock = VirtualClock()
    servo = winch_in_mode_5(1.5, profile_rad_s=0.5)  # cap far above the slip load
    world = SimWorld(preset, servo, step_devices=servo.advance_to, seed=3)
    clock.on_advance(world.advance_to)
    world.set_configuration([0.2, 0.1, 0.0, -0.2, 0.3, 0.0, 0.1, 0.0])
    trial = set_up_trial(world, "link_validation")
    reel_to(servo, 10.0, clock.monotonic_ns())
    for _ in range(400):
        clock.advance_ns(50 * MS)
        if len(world.slips) >= 2:
            break
    assert len(world.slips) >= 2
    first, second = world.slips[:2]
    assert first.onset.joint == trial.first_slip_joint
    ramp_n_per_ms = world.line.stiffness_n_per_m * preset.drum_radius_m * 0.5e-3
    assert trial.slip_force_n <= first.onset.peak_tension_n <= trial.slip_force_n + 2 * ramp_n_per_ms
    assert first.tension_after_n == pytest.approx(preset.kinetic_ratio * first.onset.peak_tension_n, rel=0.02)
    assert second.onset.onset_ns > first.end_ns
    assert math.isclose(second.onset.peak_tension_n, first.onset.peak_tension_n, rel_tol=0.02)
