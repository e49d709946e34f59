"""DynamixelServoBus against the emulated bus over the in-process transport (virtual time, deterministic)."""

from __future__ import annotations

import math
import os
import signal

import pytest
from dynamixel_sdk import PacketHandler

from rig.errors import (
    CommunicationError,
    HandshakeError,
    HardwareFault,
    LimitError,
    NotConnectedError,
    RigTimeoutError,
)
from rig.hw.dxl import units as units
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.dxl.control_table import XL430_W250
from rig.hw.dxl.error_codes import InstructionRejected, ServoHardwareFault
from rig.hw.dxl.transport import BusOwnershipError
from rig.hw.seams import OperatingMode, ServoBus
from rig.inputs.rig_config import ServoSpec
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.dxl.inprocess_port import SimPortHandler
from rig.sim.dxl.servo import Servo
from rig.sim.virtual_clock import VirtualClock


@pytest.fixture
def rig(emulated_dxl):
    r = emulated_dxl()
    r.driver.connect()
    yield r
    r.driver.shutdown()  # strict: a shutdown error fails the test


# ----------------------------------------------------------------------------- connect / handshake


def test_connect_configures_every_servo(rig):
    assert isinstance(rig.driver, ServoBus)
    for i in (1, 2, 3):
        assert rig.reg(i, "Return Delay Time") == 0
        assert rig.reg(i, "Status Return Level") == 2
    info = rig.driver.info()
    assert {i: (x.model, x.model_number, x.firmware, x.role) for i, x in info.items()} == {
        1: ("XM430-W350", 1020, 48, "winch"),
        2: ("XM430-W350", 1020, 48, "bender"),
        3: ("XM430-W350", 1020, 48, "bender"),
    }
    assert rig.driver.uses_fast_sync_read  # firmware 48 >= 45


def test_return_delay_is_written_with_torque_off_when_torque_was_on(emulated_dxl):
    r = emulated_dxl(ids=(1,))
    port = r.make_port("setup")
    assert port.openPort() and port.setBaudRate(1_000_000)
    ph = PacketHandler(2.0)
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (0, 0)  # torque on: EEPROM locked
    r.driver.connect()
    assert r.reg(1, "Return Delay Time") == 0
    assert not r.bus[1].torque_enabled
    r.driver.shutdown()


def test_old_firmware_uses_plain_sync_read(emulated_dxl):
    r = emulated_dxl(firmware=44)
    r.driver.connect()
    assert not r.driver.uses_fast_sync_read
    r.driver.read_states()
    assert r.driver.stats.sync_reads == 1 and r.driver.stats.fast_sync_reads == 0
    r.driver.shutdown()


def test_handshake_lists_missing_ids_and_wrong_models_in_one_error(emulated_dxl):
    r = emulated_dxl(ids=(1, 2))
    r.bus.add_servo(Servo(XL430_W250, 3))
    specs = [ServoSpec(1, "winch", "XM430-W350"), ServoSpec(3, "bender", "XM430-W350"),
             ServoSpec(7, "bender", "XM430-W350")]  # fmt: skip
    driver = DynamixelServoBus("sim://dxl", 1_000_000, specs, r.clock, port_factory=r.make_port, retries=1)
    with pytest.raises(HandshakeError) as exc:
        driver.connect()
    text = str(exc.value)
    assert "missing: servo 7 (bender)" in text
    assert "servo 3 (bender) expected XM430-W350 (1020), found XL430-W250 (1060)" in text
    assert "servo 1" not in text
    assert "after 2 tries" in text
    assert not r.ports[-1].is_open  # the port is closed again
    assert not driver.connected


def test_servo_at_another_baud_is_missing(emulated_dxl):
    r = emulated_dxl(ids=(1, 2), retries=0)
    r.bus[2].set_baud(57_600)
    with pytest.raises(HandshakeError, match=r"missing: servo 2 \(bender\)"):
        r.driver.connect()


def test_port_that_cannot_open_is_not_connected_error():
    clock = VirtualClock()

    def factory(name):
        raise OSError(f"could not open port {name}")

    driver = DynamixelServoBus("/dev/ttyGONE", 1_000_000, [ServoSpec(1, "winch", "XM430-W350")], clock,
                               port_factory=factory)  # fmt: skip
    with pytest.raises(NotConnectedError, match="/dev/ttyGONE"):
        driver.connect()
    driver.shutdown()  # nothing to do, no error


def test_calls_before_connect_raise_not_connected(emulated_dxl):
    r = emulated_dxl()
    with pytest.raises(NotConnectedError, match="not connected"):
        r.driver.read_states()


# ----------------------------------------------------------------------------- state reads and units


@pytest.mark.parametrize("fast", [True, False], ids=["fast-sync-read", "sync-read"])
def test_read_states_in_si_units_with_signs(fast, emulated_dxl):
    r = emulated_dxl(fast_sync_read=fast)
    d = r.driver
    d.connect()
    for i in (1, 2, 3):
        d.set_operating_mode(i, OperatingMode.EXTENDED_POSITION)
    d.set_torque([1, 2, 3], True)
    goals = {1: -7.0, 2: 12.5, 3: -0.3}
    d.write_goal_positions(goals)
    r.clock.advance_ns(5_000_000_000)
    states = d.read_states()
    assert set(states) == {1, 2, 3}
    for i, goal in goals.items():
        assert states[i].position_rad == pytest.approx(r.bus[i].present_position_rad, abs=1e-12)
        assert states[i].position_rad == pytest.approx(goal, abs=units.RAD_PER_PULSE)
        assert states[i].hardware_error == 0
        assert states[i].time_ns == r.clock.time_ns()
    # A moving servo: negative velocity and the moving flag.
    d.write_goal_positions({1: -40.0})
    r.clock.advance_ns(300_000_000)
    s1 = d.read_states()[1]
    assert s1.moving
    assert s1.velocity_rad_s < -1.0
    assert s1.velocity_rad_s == pytest.approx(
        r.bus[1].present_velocity_rad_s, abs=units.RAD_S_PER_VELOCITY_UNIT
    )
    # Current under an external load, signed.
    r.bus[2].external_torque_nm = -1.0
    r.clock.advance_ns(200_000_000)
    s2 = d.read_states()[2]
    assert s2.current_a == pytest.approx(r.bus[2].present_current_a, abs=units.CURRENT_UNIT_A)
    assert abs(s2.current_a) > 0.3
    assert d.stats.fast_sync_reads == (3 if fast else 0)
    assert d.stats.sync_reads == (0 if fast else 3)
    d.shutdown()


def test_xl430_reports_no_current(emulated_dxl):
    r = emulated_dxl(ids=(4,), model="XL430-W250")
    r.driver.connect()
    state = r.driver.read_states()[4]
    assert math.isnan(state.current_a)
    with pytest.raises(LimitError, match="no current control"):
        r.driver.write_goal_currents({4: 0.1})
    with pytest.raises(LimitError, match=r"mode 5 .*not available on XL430-W250; allowed: \[1, 3, 4, 16\]"):
        r.driver.set_operating_mode(4, OperatingMode.CURRENT_BASED_POSITION)
    r.driver.shutdown()


def test_read_health(rig):
    health = rig.driver.read_health()
    assert health[1].input_voltage_v == pytest.approx(12.0)
    assert health[2].temperature_c == pytest.approx(rig.reg(2, "Present Temperature"))
    assert health[3].hardware_error == 0


# ----------------------------------------------------------------------------- goals and limits


def test_goal_position_limits_are_checked_before_anything_is_sent(rig):
    frames = rig.bus.frames_received
    with pytest.raises(
        LimitError, match=r"servo 1 \(winch\): goal position 7.0000 rad is outside \[0.0000, 6.2817\]"
    ):
        rig.driver.write_goal_positions({2: 1.0, 1: 7.0})  # mode 3: one turn
    with pytest.raises(LimitError, match="not a finite number"):
        rig.driver.write_goal_positions({1: math.nan})
    rig.driver.set_operating_mode(1, OperatingMode.EXTENDED_POSITION)
    frames = rig.bus.frames_received
    with pytest.raises(LimitError, match="EXTENDED_POSITION"):
        rig.driver.write_goal_positions({1: 257 * 2 * math.pi})
    assert rig.bus.frames_received == frames
    rig.driver.write_goal_positions({1: -200 * 2 * math.pi})
    assert rig.reg(1, "Goal Position") == -200 * 4096


def test_goal_positions_need_a_position_mode(rig):
    rig.driver.set_operating_mode(2, OperatingMode.VELOCITY)
    with pytest.raises(LimitError, match="VELOCITY mode; goal positions need mode 3, 4 or 5"):
        rig.driver.write_goal_positions({2: 0.5})


def test_goal_currents_are_sync_written_within_the_current_limit(rig):
    rig.driver.write_goal_currents({1: 0.5, 2: -1.0})
    assert rig.reg(1, "Goal Current") == round(0.5 / units.CURRENT_UNIT_A)
    assert rig.reg(2, "Goal Current") == round(-1.0 / units.CURRENT_UNIT_A)
    with pytest.raises(LimitError, match=r"outside \+-3.209 A \(Current Limit\)"):
        rig.driver.write_goal_currents({3: 4.0})


def test_current_limit_is_written_with_torque_off_and_restored(rig):
    rig.driver.set_torque([1], True)
    rig.driver.set_current_limit(1, 1.0)
    assert rig.reg(1, "Current Limit") == round(1.0 / units.CURRENT_UNIT_A)
    assert rig.bus[1].torque_enabled
    with pytest.raises(LimitError, match=r"outside \+-1.001 A \(Current Limit\)"):
        rig.driver.write_goal_currents({1: 1.5})


# ----------------------------------------------------------------------------- operating mode


def ram(rig, servo_id):
    return tuple(rig.reg(servo_id, n) for n in ("Goal Current", "Profile Velocity", "Profile Acceleration"))


def test_mode_change_rewrites_goal_current_and_profile(rig):
    d = rig.driver
    d.set_torque([1], True)
    d.set_operating_mode(
        1, OperatingMode.CURRENT_BASED_POSITION, goal_current_a=0.8, profile_velocity_rad_s=2.0,
        profile_acceleration_rad_s2=10.0,
    )  # fmt: skip
    gc, pv, pa = (
        round(0.8 / units.CURRENT_UNIT_A),
        round(2.0 / units.RAD_S_PER_VELOCITY_UNIT),
        round(10.0 / units.RAD_S2_PER_ACCELERATION_UNIT),
    )
    assert rig.reg(1, "Operating Mode") == 5
    assert ram(rig, 1) == (gc, pv, pa)
    assert rig.bus[1].torque_enabled  # restored
    assert d.operating_mode(1) is OperatingMode.CURRENT_BASED_POSITION
    # The servo resets goal current to the Current Limit and the profile to 0 on a mode change;
    # the driver must write the previous values back even when none are given.
    d.set_operating_mode(1, OperatingMode.EXTENDED_POSITION)
    assert rig.reg(1, "Operating Mode") == 4
    assert ram(rig, 1) == (gc, pv, pa)
    assert rig.bus[1].torque_enabled


def test_mode_change_with_torque_off_leaves_torque_off(rig):
    rig.driver.set_operating_mode(2, OperatingMode.CURRENT)
    assert rig.reg(2, "Operating Mode") == 0
    assert not rig.bus[2].torque_enabled


def test_set_profile_and_its_limits(rig):
    rig.driver.set_profile(3, velocity_rad_s=1.0)
    assert rig.reg(3, "Profile Velocity") == round(1.0 / units.RAD_S_PER_VELOCITY_UNIT)
    with pytest.raises(LimitError, match="must be >= 0"):
        rig.driver.set_profile(3, velocity_rad_s=-1.0)


# ----------------------------------------------------------------------------- hardware faults and reboot


def test_injected_hardware_error_is_recorded_in_the_state_and_raised_on_commands(rig):
    d = rig.driver
    d.set_torque([1, 2], True)
    rig.bus.set_hardware_error(2, 0x20)
    states = d.read_states()
    assert states[2].hardware_error == 0x20 and states[1].hardware_error == 0
    assert d.stats.alerts >= 1
    with pytest.raises(ServoHardwareFault) as exc:
        d.raise_for_hardware_errors(states)
    assert isinstance(exc.value, HardwareFault)
    assert (exc.value.servo_id, exc.value.role, exc.value.words) == (2, "bender", ["overload"])
    with pytest.raises(ServoHardwareFault, match=r"servo 2 \(bender\): hardware error 0x20 \(overload\)"):
        d.set_torque([2], True)
    assert d.hardware_errors()[2] == 0x20


def test_real_overload_then_reboot_restores_ram_settings(emulated_dxl):
    r = emulated_dxl(ids=(1, 2))
    d = r.driver
    d.connect()
    d.set_current_limit(1, 1.0)
    d.set_operating_mode(1, OperatingMode.EXTENDED_POSITION, goal_current_a=0.5, profile_velocity_rad_s=4.0)
    d.set_torque([1, 2], True)
    r.bus[1].external_torque_nm = 20.0  # far above what 1 A holds: current sits at the limit
    r.clock.advance_ns(3_000_000_000)
    states = d.read_states()
    assert states[1].hardware_error & 0x20
    assert not r.bus[1].torque_enabled
    d.reboot(1)
    r.bus[1].external_torque_nm = 0.0
    assert d.stats.reboots == 1
    assert r.reg(1, "Hardware Error Status") == 0
    assert r.bus[1].torque_enabled  # torque as before the fault
    assert r.reg(1, "Operating Mode") == 4
    assert r.reg(1, "Goal Current") == round(0.5 / units.CURRENT_UNIT_A)
    assert r.reg(1, "Profile Velocity") == round(4.0 / units.RAD_S_PER_VELOCITY_UNIT)
    assert d.read_states()[1].hardware_error == 0
    d.shutdown()


def test_reboots_are_bounded_per_run(emulated_dxl):
    r = emulated_dxl(ids=(1,), max_reboots=1)
    r.driver.connect()
    r.driver.reboot(1)
    with pytest.raises(
        HardwareFault, match=r"refusing to reboot servo 1 \(winch\): 1 reboot\(s\) .* \(limit 1\)"
    ):
        r.driver.reboot(1)
    assert r.driver.reboots_left == 0
    r.driver.shutdown()


def test_reboot_of_a_servo_that_never_comes_back_times_out_in_bounded_time(emulated_dxl):
    r = emulated_dxl(ids=(1, 2), reboot_timeout_s=0.5)
    r.driver.connect()
    t0 = r.clock.monotonic_ns()
    r.bus.set_silent(2)
    with pytest.raises(RigTimeoutError, match=r"servo 2 \(bender\) did not answer a ping within 0.5 s"):
        r.driver.reboot(2)
    assert (r.clock.monotonic_ns() - t0) / 1e9 < 2.0
    r.bus.set_silent(2, False)
    r.driver.shutdown()


# ----------------------------------------------------------------------------- retries and typed errors


@pytest.mark.parametrize("fast", [True, False], ids=["fast-sync-read", "sync-read"])
@pytest.mark.parametrize("fault", ["drop", "corrupt", "delay"])
def test_one_bad_reply_is_retried_and_counted(fault, fast, emulated_dxl):
    r = emulated_dxl(fast_sync_read=fast)
    d = r.driver
    d.connect()
    before = d.stats
    if fault == "drop":
        r.bus.faults.drop_next(1)
    elif fault == "corrupt":
        r.bus.faults.corrupt_next(1)
    else:
        r.bus.faults.delay_next(1, delay_s=0.2)  # arrives long after the SDK's window
    states = d.read_states()
    after = d.stats
    assert set(states) == {1, 2, 3}
    assert after.retries - before.retries == 1
    assert after.recovered - before.recovered == 1
    assert after.failures == before.failures
    if fault == "corrupt":
        assert after.corrupt - before.corrupt == 1
    else:
        assert after.timeouts - before.timeouts == 1
    # The late reply must not be mistaken for a later answer.
    r.clock.advance_ns(300_000_000)
    assert d.read_states()[2].position_rad == pytest.approx(r.bus[2].present_position_rad)
    d.shutdown()


def test_persistent_timeouts_raise_after_counted_tries_and_name_the_silent_servo(rig):
    rig.bus.set_silent(3)
    with pytest.raises(RigTimeoutError) as exc:
        rig.driver.read_states()
    text = str(exc.value)
    assert "failed after 3 tries" in text
    assert "not answering a ping: servo 3 (bender)" in text
    assert rig.driver.stats.failures == 1
    rig.bus.set_silent(3, False)


def test_persistent_corruption_is_a_communication_error(rig):
    rig.bus.faults.corrupt_next(10)
    with pytest.raises(CommunicationError, match="failed after 3 tries: corrupt status packet"):
        rig.driver.read_states()
    rig.bus.faults.clear()


def test_retries_zero_means_one_try(emulated_dxl):
    r = emulated_dxl(ids=(1,), retries=0)
    r.driver.connect()
    r.bus.faults.drop_next(1)
    with pytest.raises(RigTimeoutError, match="after 1 try"):
        r.driver.read_hardware_error(1)
    r.driver.shutdown()


def test_dropped_replies_during_handshake_are_recovered(emulated_dxl):
    r = emulated_dxl(retries=2)
    r.bus.faults.drop_next(2, servo_id=2)
    r.driver.connect()
    assert r.driver.stats.recovered >= 1
    assert r.driver.stats.timeouts == 2
    r.driver.shutdown()


@pytest.mark.parametrize("dropped", [3, 8])
def test_a_burst_of_lost_replies_does_not_fail_the_handshake(emulated_dxl, dropped):
    # Three replies lost in a row used to fail the connect (one ping and its two retries).
    r = emulated_dxl(retries=2)
    r.bus.faults.drop_next(dropped, servo_id=2)
    r.driver.connect()
    assert r.driver.info()[2].model == "XM430-W350"
    r.driver.shutdown()


def test_a_servo_that_never_answers_is_still_reported_missing(emulated_dxl):
    r = emulated_dxl(retries=2)
    r.bus.faults.drop_next(9, servo_id=2)
    with pytest.raises(HandshakeError, match=r"missing: servo 2"):
        r.driver.connect()


@pytest.mark.parametrize("settle_s", [0.002, 0.0], ids=["settle-and-clear", "length-check-only"])
def test_late_write_status_is_not_taken_for_a_read_reply(settle_s, emulated_dxl):
    # The write's status arrives just after the SDK gave up on it. Two defences: the driver settles
    # and clears the port before a retry, and it checks every status's LEN against what was asked
    # (the SDK's read1ByteTxRx would return the late write status's CRC byte, 0xA1, as the value).
    r = emulated_dxl(ids=(1,), retry_settle_s=settle_s)
    r.driver.connect()
    r.bus.faults.delay_next(1, delay_s=0.0345, servo_id=1)
    r.driver.set_profile(1, velocity_rad_s=1.0)
    assert r.driver.read_hardware_error(1) == 0
    assert r.reg(1, "Profile Velocity") == round(1.0 / units.RAD_S_PER_VELOCITY_UNIT)
    r.driver.shutdown()


def test_refused_instruction_is_a_typed_error_naming_the_servo(rig):
    # Torque turned on behind the driver's back: the EEPROM write is refused with an Access error.
    ph = PacketHandler(2.0)
    assert ph.write1ByteTxRx(rig.ports[0], 1, 64, 1) == (0, 0)
    with pytest.raises(
        InstructionRejected, match=r"servo 1 \(winch\) rejected the write of Current Limit=.*access"
    ):
        rig.driver.set_current_limit(1, 1.0)


class _RaisingPort(SimPortHandler):
    """Raises like the SDK does on a short packet, once."""

    raise_next = 0

    def readPort(self, length):
        if _RaisingPort.raise_next:
            _RaisingPort.raise_next -= 1
            raise IndexError("list index out of range")
        return super().readPort(length)


def test_sdk_exceptions_become_counted_retries_not_leaks():
    clock = VirtualClock()
    bus = EmulatedBus.with_servos(clock, ids=[1])
    d = DynamixelServoBus("sim", 1_000_000, [ServoSpec(1, "winch", "XM430-W350")], clock,
                          port_factory=lambda n: _RaisingPort(bus, clock, n))  # fmt: skip
    d.connect()
    _RaisingPort.raise_next = 1
    d.read_states()
    assert d.stats.corrupt == 1 and d.stats.recovered == 1
    _RaisingPort.raise_next = 5
    with pytest.raises(CommunicationError, match="SDK raised IndexError"):
        d.read_states()
    _RaisingPort.raise_next = 0
    d.shutdown()


def test_reentrant_use_is_refused():
    clock = VirtualClock()
    bus = EmulatedBus.with_servos(clock, ids=[1])
    holder = {}

    class Reentrant(SimPortHandler):
        def writePort(self, packet):
            if holder.get("armed"):
                holder["armed"] = False
                with pytest.raises(BusOwnershipError, match="re-entrantly"):
                    holder["driver"].read_states()
                holder["refused"] = True
            return super().writePort(packet)

    d = DynamixelServoBus("sim", 1_000_000, [ServoSpec(1, "winch", "XM430-W350")], clock,
                          port_factory=lambda n: Reentrant(bus, clock, n))  # fmt: skip
    holder["driver"] = d
    d.connect()
    holder["armed"] = True
    d.read_states()
    assert holder["refused"]
    d.shutdown()


def test_bus_watchdog_is_set_when_asked(emulated_dxl):
    r = emulated_dxl(ids=(1,), bus_watchdog_ms=100)
    r.driver.connect()
    assert r.reg(1, "Bus Watchdog") == 5  # 20 ms units
    r.driver.shutdown()


# ----------------------------------------------------------------------------- shutdown


def test_shutdown_releases_first_then_torques_off_then_closes(rig):
    d = rig.driver
    d.set_torque([1, 2, 3], True)
    seen = []

    def release():
        seen.append([rig.bus[i].torque_enabled for i in (1, 2, 3)])
        d.write_goal_currents({1: 0.0})  # the release action may still command the bus

    d.shutdown(release)
    assert seen == [[True, True, True]]
    assert [rig.bus[i].torque_enabled for i in (1, 2, 3)] == [False, False, False]
    assert not rig.ports[0].is_open
    assert not d.connected
    d.shutdown(release)  # idempotent: release is not called again
    assert len(seen) == 1
    with pytest.raises(NotConnectedError, match="shut down"):
        d.read_states()


def test_shutdown_keeps_going_and_reraises_the_first_error(rig):
    d = rig.driver
    d.set_torque([1, 2, 3], True)
    rig.bus.set_silent(2)

    def release():
        raise ValueError("winch stuck")

    with pytest.raises(ValueError, match="winch stuck") as exc:
        d.shutdown(release)
    notes = " ".join(getattr(exc.value, "__notes__", []))
    assert "servo 2 (bender)" in notes and "RigTimeoutError" in notes
    # The broadcast torque-off reached everyone who listens; 1 and 3 are confirmed off.
    assert not rig.bus[1].torque_enabled and not rig.bus[3].torque_enabled
    assert not rig.ports[0].is_open


def test_keyboard_interrupt_in_release_still_torques_off(rig):
    rig.driver.set_torque([1, 3], True)

    def release():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        rig.driver.shutdown(release)
    assert not rig.bus[1].torque_enabled and not rig.bus[3].torque_enabled


def test_ctrl_c_during_torque_off_is_held_until_every_servo_is_off(rig):
    rig.driver.set_torque([1, 2, 3], True)
    port = rig.ports[0]
    write = port.writePort
    armed = []

    def interrupted_write(packet):
        if armed:  # the first packet after the release: the broadcast torque-off
            armed.clear()
            os.kill(os.getpid(), signal.SIGINT)
        return write(packet)

    port.writePort = interrupted_write
    with pytest.raises(KeyboardInterrupt):
        rig.driver.shutdown(lambda: armed.append(True))
    assert [rig.bus[i].torque_enabled for i in (1, 2, 3)] == [False, False, False]
    assert not port.is_open


def test_context_manager_shuts_down_with_the_configured_release(emulated_dxl):
    calls = []
    r = emulated_dxl(ids=(1,), release=lambda: calls.append("release"))
    with pytest.raises(RuntimeError, match="boom"), r.driver as d:
        d.set_torque([1], True)
        raise RuntimeError("boom")
    assert calls == ["release"]
    assert not r.bus[1].torque_enabled
    assert not r.driver.connected
