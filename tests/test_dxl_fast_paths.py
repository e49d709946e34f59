"""The emulator's fast paths against straightforward reference versions of the same computations.

CRC-16 by words, the one-pass fast-read reply, the framer's repeat shortcut, the actuator's hoisted
step and the cached present block must give the same bytes and the same floats (bit for bit) as
the plain code they replaced; the references here are that plain code.
"""

from __future__ import annotations

import math
import random

from hypothesis import given, settings
from hypothesis import strategies as st

from rig.hw.dxl.control_table import table_for_model
from rig.sim.dxl import packet as p
from rig.sim.dxl.actuator import (
    ActuatorCommand,
    ActuatorState,
    MotorParams,
    ProfiledActuator,
    profile_step,
)
from rig.sim.dxl.servo import Servo


def reference_crc16(data: bytes, crc: int = 0) -> int:
    """Byte at a time, straight from the table."""
    for b in data:
        crc = ((crc << 8) ^ p.CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def reference_fast_status(entries: list[tuple[int, int, bytes]], announced: int) -> bytes:
    """CRC over the whole packet so far, recomputed after every entry."""
    out = bytearray(p.HEADER) + bytes(
        (p.BROADCAST_ID, announced & 0xFF, announced >> 8, p.STATUS_INSTRUCTION)
    )
    for error, servo_id, data in entries:
        out += bytes((error, servo_id)) + data
        crc = reference_crc16(bytes(out))
        out += bytes((crc & 0xFF, crc >> 8))
    return bytes(out)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 0xFFFF), st.sampled_from([bytes, bytearray, memoryview, list]))
def test_crc16_matches_bytewise(data: bytes, init: int, kind: type) -> None:
    assert p.crc16(kind(data), init) == reference_crc16(data, init)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 255), st.integers(0, 252), st.binary(max_size=30)), min_size=1, max_size=5
    )
)
def test_fast_status_matches_reference(entries: list[tuple[int, int, bytes]]) -> None:
    announced = 1 + sum(len(d) + 4 for _, _, d in entries)
    assert p.build_fast_status(entries) == reference_fast_status(entries, announced)
    assert p.build_fast_status(entries, announced + 7) == reference_fast_status(entries, announced + 7)


def test_framer_repeat_shortcut_still_checks_changed_bytes() -> None:
    good = p.build_instruction(p.BROADCAST_ID, p.FAST_SYNC_READ, bytes((122, 0, 14, 0, 1, 2)), stuffed=False)
    bad = good[:-1] + bytes(((good[-1] + 1) & 0xFF,))
    framer = p.Framer()
    results = [frame.crc_ok for data in (good, good, bad, bad, good) for frame in framer.feed(data, 0)]
    assert results == [True, True, False, False, True]


# ----- actuator --------------------------------------------------------------------------------------


def _sign(x: float) -> float:
    return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)


def reference_profile_step(
    ref_rad: float, ref_v: float, goal_rad: float, v_max: float, a_max: float, dt_s: float
) -> tuple[float, float, bool]:
    d = goal_rad - ref_rad
    if math.isinf(a_max):
        v = max(-v_max, min(v_max, d / dt_s))
        new = ref_rad + v * dt_s
        if abs(goal_rad - new) < 1e-12:
            return goal_rad, 0.0, True
        return new, v, False
    if abs(d) < 1e-12 and abs(ref_v) <= a_max * dt_s:
        return goal_rad, 0.0, True
    v_stop = math.sqrt(2.0 * a_max * abs(d))
    v_target = _sign(d) * min(v_max, v_stop)
    dv = a_max * dt_s
    v = min(v_target, ref_v + dv) if v_target > ref_v else max(v_target, ref_v - dv)
    new = ref_rad + 0.5 * (ref_v + v) * dt_s
    if (goal_rad - new) * d <= 0.0 and abs(v) <= 2.0 * dv + 1e-12:
        return goal_rad, 0.0, True
    return new, v, False


class ReferenceActuator:
    """The actuator as first written: MotorParams properties and min/max on every step."""

    def __init__(self, params: MotorParams) -> None:
        self.params = params

    def step(self, state: ActuatorState, cmd: ActuatorCommand, dt_s: float, tau_ext: float) -> None:
        p_ = self.params
        if not cmd.torque_enabled:
            state.motor_torque_nm = 0.0
            state.velocity_rad_s = self._passive(tau_ext, p_.backdrive_nm_s)
            state.position_rad += state.velocity_rad_s * dt_s
            state.ref_position_rad, state.ref_velocity_rad_s = state.position_rad, 0.0
            state.saturated, state.profile_done = False, True
            return
        mode = cmd.mode
        if mode == 0:
            tau_m = max(-cmd.torque_limit_nm, min(cmd.torque_limit_nm, cmd.goal_torque_nm))
            self._open_loop(state, tau_m, tau_ext, dt_s)
            state.saturated = (
                abs(tau_m) >= cmd.torque_limit_nm > 0 and abs(cmd.goal_torque_nm) >= cmd.torque_limit_nm
            )
            return
        if mode == 16:
            self._open_loop(state, cmd.pwm_fraction * p_.stall_torque_nm, tau_ext, dt_s, line=True)
            state.saturated = False
            return
        v_cap = min(p_.no_load_speed_rad_s, cmd.profile_velocity_rad_s)
        if mode == 1:
            goal_v = max(-v_cap, min(v_cap, cmd.goal_velocity_rad_s))
            a = cmd.profile_acceleration_rad_s2
            dv = math.inf if math.isinf(a) else a * dt_s
            rv = state.ref_velocity_rad_s
            rv = min(goal_v, rv + dv) if goal_v > rv else max(goal_v, rv - dv)
            state.ref_velocity_rad_s = rv
            state.profile_done = rv == goal_v
            desired = rv
        else:
            err = state.ref_position_rad - state.position_rad
            if not state.profile_done or state.ref_position_rad != cmd.goal_position_rad:
                ref, rv, done = reference_profile_step(
                    state.ref_position_rad,
                    state.ref_velocity_rad_s,
                    cmd.goal_position_rad,
                    v_cap,
                    cmd.profile_acceleration_rad_s2,
                    dt_s,
                )
                state.ref_position_rad, state.ref_velocity_rad_s, state.profile_done = ref, rv, done
            desired = state.ref_velocity_rad_s + p_.position_gain_per_s * err
            desired = max(-p_.no_load_speed_rad_s, min(p_.no_load_speed_rad_s, desired))
            if (
                state.profile_done
                and abs(state.ref_position_rad - state.position_rad) < 1e-4
                and not state.saturated
            ):
                desired = 0.0
                state.position_rad = state.ref_position_rad
        self._track(state, desired, cmd.torque_limit_nm, tau_ext, dt_s)
        if mode == 1:
            state.ref_position_rad = state.position_rad

    def _passive(self, net: float, damping: float) -> float:
        c = self.params.coulomb_nm
        if abs(net) <= c:
            return 0.0
        v = (net - _sign(net) * c) / damping
        limit = 2.0 * self.params.no_load_speed_rad_s
        return max(-limit, min(limit, v))

    def _open_loop(
        self, state: ActuatorState, tau_m: float, tau_ext: float, dt_s: float, line: bool = False
    ) -> None:
        p_ = self.params
        net = tau_m + tau_ext
        damping = p_.viscous_nm_s + (p_.backdrive_nm_s if line else 0.0)
        if _sign(net) != _sign(tau_m):
            damping = p_.backdrive_nm_s
        v = self._passive(net, damping)
        if line:
            tau_m -= p_.backdrive_nm_s * v
        state.motor_torque_nm = tau_m
        state.velocity_rad_s = v
        state.position_rad += v * dt_s
        state.ref_position_rad, state.ref_velocity_rad_s = state.position_rad, v

    def _track(self, state: ActuatorState, desired: float, limit: float, tau_ext: float, dt_s: float) -> None:
        p_ = self.params
        limit = min(limit, p_.stall_torque_nm)
        if desired == 0.0:
            needed = -tau_ext
        else:
            needed = p_.viscous_nm_s * desired + p_.coulomb_nm * _sign(desired) - tau_ext
        if abs(needed) <= limit:
            state.motor_torque_nm = needed
            state.velocity_rad_s = desired
            state.saturated = False
        else:
            tau_m = _sign(needed) * limit
            net = tau_m + tau_ext
            damping = p_.viscous_nm_s if _sign(net) == _sign(tau_m) else p_.backdrive_nm_s
            state.motor_torque_nm = tau_m
            state.velocity_rad_s = self._passive(net, damping)
            state.saturated = True
        state.position_rad += state.velocity_rad_s * dt_s


def _random_command(rng: random.Random) -> ActuatorCommand:
    def speed() -> float:
        return rng.choice([math.inf, 0.0, rng.uniform(0.0, 10.0)])

    return ActuatorCommand(
        torque_enabled=rng.random() < 0.9,
        mode=rng.choice([0, 1, 3, 4, 5, 5, 5, 16]),
        goal_position_rad=rng.choice([0.0, rng.uniform(-20.0, 20.0)]),
        goal_velocity_rad_s=rng.uniform(-8.0, 8.0),
        goal_torque_nm=rng.uniform(-5.0, 5.0),
        pwm_fraction=rng.uniform(-1.0, 1.0),
        torque_limit_nm=rng.choice([0.0, rng.uniform(0.0, 5.0)]),
        profile_velocity_rad_s=speed(),
        profile_acceleration_rad_s2=rng.choice([math.inf, rng.uniform(0.1, 200.0)]),
    )


def test_actuator_step_matches_reference_bit_for_bit() -> None:
    rng = random.Random(20261121)
    params = MotorParams(4.1, 2.3, 4.8)
    fast, ref = ProfiledActuator(params), ReferenceActuator(params)
    for _ in range(300):
        cmd = _random_command(rng)
        a, b = ActuatorState(position_rad=rng.uniform(-5, 5)), ActuatorState()
        a.ref_position_rad = rng.choice([a.position_rad, rng.uniform(-5, 5)])
        a.profile_done = rng.random() < 0.5
        for field in ActuatorState.__slots__:
            setattr(b, field, getattr(a, field))
        for _ in range(200):
            tau = rng.choice([0.0, rng.uniform(-6.0, 6.0)])
            dt = rng.choice([1e-3, 1e-3, rng.uniform(1e-5, 1e-3)])
            fast.step(a, cmd, dt, tau)
            ref.step(b, cmd, dt, tau)
            assert [getattr(a, f) for f in ActuatorState.__slots__] == [
                getattr(b, f) for f in ActuatorState.__slots__
            ]
            assert all(
                math.copysign(1.0, getattr(a, f)) == math.copysign(1.0, getattr(b, f))
                for f in ("position_rad", "velocity_rad_s", "motor_torque_nm", "ref_velocity_rad_s")
            )


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-10, 10),
    st.floats(-5, 5),
    st.floats(-10, 10),
    st.sampled_from([0.0, 0.5, 4.8, math.inf]),
    st.sampled_from([math.inf, 0.0, 3.0, 50.0]),
    st.sampled_from([1e-3, 2.5e-4]),
)
def test_profile_step_matches_reference(
    ref: float, ref_v: float, goal: float, v_max: float, a_max: float, dt: float
) -> None:
    got, want = (
        profile_step(ref, ref_v, goal, v_max, a_max, dt),
        reference_profile_step(ref, ref_v, goal, v_max, a_max, dt),
    )
    assert repr(got) == repr(want)  # repr tells -0.0 from 0.0


# ----- cached present block ---------------------------------------------------------------------------


def test_cached_present_block_equals_a_fresh_encoding() -> None:
    """Two identical servos, one of which forgets its cache before every read: same bytes throughout."""
    table = table_for_model("XM430-W350")
    cached, fresh = (Servo(table, 1, boot_time_s=0.01) for _ in range(2))
    rng = random.Random(7)
    now = 0
    for k in range(1500):
        now += rng.choice([1, 1_000_000, 1_000_000, 7_300_000])
        tau = rng.choice([0.0, 0.0, rng.uniform(-0.5, 0.5)])
        action = rng.random()
        for servo in (cached, fresh):
            servo.external_torque_nm = tau
            if action < 0.05:
                servo.write(64, bytes((k & 1,)), now)  # torque on/off
            elif action < 0.1:
                servo.write(
                    116, random.Random(k).randrange(-4000, 8000).to_bytes(4, "little", signed=True), now
                )
            elif action < 0.12:
                servo.write(108, random.Random(k).choice([0, 20]).to_bytes(4, "little"), now)
            elif action < 0.13:
                servo.reboot(now)
            elif action < 0.14 and not servo.torque_enabled:
                servo.write(10, bytes((k & 1,)), now)  # Drive Mode reverse
            servo.advance_to(now)
        fresh._present_key = None
        a, b = cached.read(120, 27, now), fresh.read(120, 27, now)
        assert a == b


def test_reboot_re_encodes_the_present_block() -> None:
    """A reboot resets RAM, present registers included, although nothing the block depends on changed."""
    servo = Servo(table_for_model("XM430-W350"), 1, boot_time_s=0.01, initial_position_rad=1.0)
    before = servo.read(122, 25, 1_000_000).params
    servo.reboot(2_000_000)
    after = servo.read(122, 25, 20_000_000).params
    assert after == before and int.from_bytes(after[10:14], "little") == round(1.0 / (2 * math.pi / 4096))
