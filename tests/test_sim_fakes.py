"""The object-level fakes of the seams (rig/testing/fakes.py) do what the runner tests rely on."""

from __future__ import annotations

import math

import pytest

from rig.errors import CommunicationError, HardwareFault, NotConnectedError, StaleDataError
from rig.hw.seams import LineStatsSource, LoadCell, LoadCellLineStats, OperatingMode, ServoBus
from rig.sim.clock import VirtualClock
from rig.testing.fakes import FakeLine, FakeLoadCell, FakeServoBus, fake_rig

MS = 1_000_000


def connected_bus(**kwargs) -> tuple[VirtualClock, FakeServoBus]:
    clock = VirtualClock()
    bus = FakeServoBus(clock, [1, 2], **kwargs)
    bus.connect()
    bus.set_operating_mode(1, OperatingMode.CURRENT_BASED_POSITION, profile_velocity_rad_s=1.0)
    bus.set_torque([1, 2], True)
    return clock, bus


def test_fakes_implement_the_seams():
    rig = fake_rig()
    assert isinstance(rig.servos, ServoBus) and isinstance(rig.load_cell, LoadCell)
    assert rig.session.roles == {1: "winch"} and rig.session.winch_id == 1


def test_servo_moves_at_the_profile_velocity_then_settles_first_order():
    clock, bus = connected_bus(time_constant_s=0.05)
    bus.write_goal_positions({1: 2.0})
    clock.advance_ns(1000 * MS)
    state = bus.read_states()[1]
    assert state.position_rad == pytest.approx(1.0) and state.velocity_rad_s == pytest.approx(1.0)
    assert state.moving and state.time_ns == clock.time_ns()
    clock.advance_ns(2000 * MS)
    state = bus.read_states()[1]
    assert state.position_rad == pytest.approx(2.0, abs=1e-6) and not state.moving
    # Without a profile velocity the motion is first order from the start: 1 - e^-1 after tau.
    bus.set_profile(2, velocity_rad_s=0.0)
    bus.write_goal_positions({2: 1.0})
    clock.advance_ns(50 * MS)
    assert bus.read_states()[2].position_rad == pytest.approx(1 - math.exp(-1))


def test_torque_off_holds_still_and_every_call_is_recorded():
    clock, bus = connected_bus()
    bus.set_torque([1], False)
    bus.write_goal_positions({1: 5.0})
    clock.advance_ns(500 * MS)
    assert bus.read_states()[1].position_rad == 0.0
    assert bus.call_names() == [
        "connect",
        "set_operating_mode",
        "set_torque",
        "set_torque",
        "write_goal_positions",
    ]
    assert bus.call_names(reads=True)[-1] == "read_states"
    assert bus.calls_to("write_goal_positions")[0].args == {"goals_rad": {1: 5.0}}


def test_hardware_error_at_a_time_drops_the_torque_there():
    clock, bus = connected_bus()
    bus.write_goal_positions({1: 10.0})
    bus.inject_hardware_error(1, 0x20, at_ns=300 * MS)
    clock.advance_ns(1000 * MS)
    state = bus.read_states()[1]
    assert state.hardware_error == 0x20 and not bus.servo(1).torque_enabled
    assert state.position_rad == pytest.approx(0.3) and state.velocity_rad_s == 0.0
    assert bus.motion_at(1, 200 * MS)[0] == pytest.approx(0.2)  # the past is kept
    with pytest.raises(HardwareFault, match="0x20"):
        bus.set_torque([1], True)
    bus.reboot(1)
    bus.set_torque([1], True)
    assert bus.read_states()[1].hardware_error == 0


def test_silent_bus_raises_communication_error_and_unconnected_bus_not_connected():
    clock = VirtualClock()
    bus = FakeServoBus(clock, [1])
    with pytest.raises(NotConnectedError, match="not connected"):
        bus.read_states()
    bus.connect()
    bus.silent = True
    with pytest.raises(CommunicationError, match="read_states"):
        bus.read_states()
    assert bus.call_names(reads=True)[-1] == "read_states"  # recorded even when it fails


def test_shutdown_releases_then_torques_off_then_closes_once():
    _, bus = connected_bus()

    def release():
        bus.write_goal_positions({1: 0.0})
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        bus.shutdown(release)
    assert bus.call_names()[-4:] == ["shutdown", "write_goal_positions", "torque_off", "close"]
    assert not bus.servo(1).torque_enabled and not bus.servo(2).torque_enabled and bus.closed
    bus.shutdown()  # idempotent
    assert bus.call_names()[-1] == "close"
    with pytest.raises(NotConnectedError, match="shut down"):
        bus.read_states()


def test_load_cell_samples_at_its_rate_and_goes_stale_like_the_driver():
    clock = VirtualClock()
    cell = FakeLoadCell(clock, lambda t_ns: t_ns / 1e9, rate_hz=1000, stale_timeout_s=0.2)
    with pytest.raises(NotConnectedError, match="not open"):
        cell.poll()
    cell.open()
    clock.advance_ns(100 * MS)
    samples = cell.poll()
    assert len(samples) == 100 and cell.poll() == []
    assert samples[-1].time_ns == clock.time_ns() and samples[-1].force_n == pytest.approx(0.1)
    assert [s.seq for s in samples] == list(range(1, 101)) and samples[-1].raw == 100
    cell.silence(0.5)
    clock.advance_ns(200 * MS)
    assert cell.poll() == []  # silent, but not yet for longer than the timeout
    clock.advance_ns(1 * MS)
    with pytest.raises(StaleDataError, match=r"no valid sample for 0\.201 s; limit 0\.2 s"):
        cell.poll()
    clock.advance_ns(400 * MS)
    back = cell.poll()  # the samples since the silence ended, at 600 ms
    assert [s.time_ns - clock.time_ns() for s in (back[0], back[-1])] == [-101 * MS, 0]
    assert back[0].seq == 600  # the device counted on through the silence
    assert isinstance(cell, LineStatsSource)
    assert cell.line_stats() == LoadCellLineStats(100 + len(back), 0, 0, 499, 1, 0)  # seq 101-599
    cell.disconnect("cable pulled")
    with pytest.raises(NotConnectedError, match="reading failed: cable pulled"):
        cell.poll()
    cell.close()
    assert [c.name for c in cell.calls] == ["open", "close"] and not cell.is_open


def test_line_tension_follows_the_winch_and_slips_once_per_loading():
    clock, bus = connected_bus()
    line = FakeLine(bus, 1, stiffness_n_per_rad=50.0, slip_forces_n=[20.0, 12.0], drop_fraction=0.4)
    bus.write_goal_positions({1: 10.0})  # 1 rad/s: 50 N/s
    tensions = []
    for _ in range(500):
        clock.advance_ns(1 * MS)
        tensions.append(line.tension_at(clock.monotonic_ns()))
    assert tensions[99] == pytest.approx(5.0)
    assert len(line.slips) == 1 and line.slips[0].force_n == pytest.approx(20.0)
    assert line.slips[0].force_after_n == pytest.approx(12.0)
    assert 19.9 < max(tensions) < 20.0 and min(tensions[400:]) > 12.0  # not armed for the next slip yet
    bus.write_goal_positions({1: 0.0})
    clock.advance_ns(2000 * MS)
    assert line.tension_at(clock.monotonic_ns()) == 0.0  # unloaded: the next slip is armed
    bus.set_torque([1], False)
    assert line.tension_at(clock.monotonic_ns()) == 0.0  # a torque-off winch holds no tension
