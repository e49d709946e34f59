"""Servo semantics through the real SDK, in-process transport: instructions, errors, faults, motion."""

from __future__ import annotations

import itertools
import math

import pytest
from dynamixel_sdk import (
    BROADCAST_ID,
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
)

from rig.hw.dxl.control_table import RAD_PER_PULSE, XM430_W350
from rig.sim.dxl import packet as p
from tests.helpers import s16, s32, u32

ACCESS, LIMIT, RANGE, LENGTH, FAIL, INSTRUCTION, CRC = 7, 6, 4, 5, 1, 2, 3
ALERT = 0x80
# Addresses
TORQUE, MODE, GOAL_POS, PRESENT_POS, HW_ERR, GOAL_CUR, PRESENT_CUR = 64, 11, 116, 132, 70, 102, 126


@pytest.fixture
def rig(sdk_on_emulated_bus):
    return sdk_on_emulated_bus()


# ----- reads and writes of every size ------------------------------------------------------------------


def test_reads_and_writes_of_1_2_4_bytes(rig):
    assert rig.r2(1, 0) == (1020, COMM_SUCCESS, 0)
    assert rig.r1(1, 6) == (48, COMM_SUCCESS, 0)
    assert rig.r1(2, 7) == (2, COMM_SUCCESS, 0)
    assert rig.w1(1, 65, 1) == (COMM_SUCCESS, 0)
    assert rig.r1(1, 65) == (1, COMM_SUCCESS, 0)
    assert rig.w2(1, 84, 1234) == (COMM_SUCCESS, 0)
    assert rig.r2(1, 84) == (1234, COMM_SUCCESS, 0)
    assert rig.w4(1, 112, 77) == (COMM_SUCCESS, 0)
    assert rig.r4(1, 112) == (77, COMM_SUCCESS, 0)
    data, result, error = rig.ph.readTxRx(rig.port, 1, 0, 147)  # a whole block, gaps read as zero
    assert (result, error, len(data)) == (COMM_SUCCESS, 0, 147)
    assert data[14:20] == [0] * 6 and data[84] | (data[85] << 8) == 1234


def test_value_with_ff_ff_fd_round_trips_through_stuffing(rig):
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, 0)
    value = -131073  # little-endian FF FF FD FF: the status packet must be stuffed
    assert u32(value).to_bytes(4, "little") == b"\xff\xff\xfd\xff"
    assert rig.w4(1, GOAL_POS, value) == (COMM_SUCCESS, 0)
    raw, result, error = rig.r4(1, GOAL_POS)
    assert (s32(raw), result, error) == (value, COMM_SUCCESS, 0)
    # And the bytes on the wire really were stuffed.
    reply = rig.bus.feed(
        p.build_instruction(1, p.READ, bytes.fromhex("74 00 04 00")), rig.clock.monotonic_ns()
    )
    assert b"\xff\xff\xfd\xfd\xff" in reply[0].data


def test_broadcast_write_and_reply_policy(rig):
    assert rig.w1(BROADCAST_ID, 65, 1) == (COMM_SUCCESS, 0)
    assert [rig.r1(i, 65)[0] for i in (1, 2, 3)] == [1, 1, 1]
    # Status Return Level 1: reads answer, writes are silent (the SDK then times out).
    assert rig.w1(2, 68, 1) == (COMM_SUCCESS, 0)
    assert rig.w1(2, 65, 0)[0] == COMM_RX_TIMEOUT
    assert rig.r1(2, 65) == (0, COMM_SUCCESS, 0)
    # Level 0: only ping.
    rig.bus.feed(p.build_instruction(2, p.WRITE, bytes((68, 0, 0))), rig.clock.monotonic_ns())
    assert rig.r1(2, 65)[1] == COMM_RX_TIMEOUT
    assert rig.ph.ping(rig.port, 2)[1] == COMM_SUCCESS


def test_return_delay_time_sets_reply_timing(rig):
    t0 = rig.clock.monotonic_ns()
    rig.ph.ping(rig.port, 1)
    default = rig.clock.monotonic_ns() - t0
    assert rig.w1(1, 9, 0) == (COMM_SUCCESS, 0)
    t0 = rig.clock.monotonic_ns()
    rig.ph.ping(rig.port, 1)
    assert default - (rig.clock.monotonic_ns() - t0) == 500_000  # 250 x 2 us


# ----- error paths ------------------------------------------------------------------------------------


def test_access_errors(rig):
    assert rig.w4(1, PRESENT_POS, 5) == (COMM_SUCCESS, ACCESS)  # read-only
    assert rig.w1(1, 14, 0) == (COMM_SUCCESS, ACCESS)  # undefined address
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, ACCESS)  # EEPROM while torque on
    assert rig.r1(1, MODE) == (3, COMM_SUCCESS, 0)
    data, result, error = rig.ph.readTxRx(rig.port, 1, 660, 4)  # beyond the table end: no params
    assert (result, error) == (COMM_SUCCESS, ACCESS)
    assert len(data) == 2  # no params: the SDK hands back the CRC bytes (read4 would IndexError)
    rx = rig.bus.feed(p.build_instruction(1, p.READ, bytes.fromhex("94 02 04 00")), rig.clock.monotonic_ns())
    status = p.parse_status(rx[0].data)
    assert (status.error, status.params) == (ACCESS, b"")


def test_data_range_length_and_limit(rig):
    assert rig.w1(1, 68, 3) == (COMM_SUCCESS, RANGE)
    assert rig.w1(1, MODE, 2) == (COMM_SUCCESS, RANGE)  # not a mode
    assert rig.ph.writeTxRx(rig.port, 1, GOAL_POS, 2, [0, 1]) == (COMM_SUCCESS, LENGTH)  # half a field
    assert rig.w4(1, 48, 3000) == (COMM_SUCCESS, 0)  # Max Position Limit
    assert rig.w4(1, GOAL_POS, 3500) == (COMM_SUCCESS, LIMIT)  # mode 3 beyond the limit
    assert rig.w4(1, GOAL_POS, 2999) == (COMM_SUCCESS, 0)
    assert rig.w4(1, 104, 300) == (COMM_SUCCESS, LIMIT)  # beyond Velocity Limit 200
    assert rig.w2(1, GOAL_CUR, 1200) == (COMM_SUCCESS, RANGE)  # beyond the static range
    assert rig.w2(1, 38, 500) == (COMM_SUCCESS, 0)
    assert rig.w2(1, GOAL_CUR, 600) == (COMM_SUCCESS, LIMIT)  # beyond the Current Limit
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, 0)
    assert rig.w4(1, GOAL_POS, 1_048_575) == (COMM_SUCCESS, 0)
    assert rig.w4(1, GOAL_POS, 1_048_576) == (COMM_SUCCESS, RANGE)


def test_write_validates_every_field_before_applying_any(rig):
    # Torque Enable (64) = 1 is fine, LED (65) = 5 is not: nothing may be applied.
    assert rig.ph.writeTxRx(rig.port, 1, 64, 2, [1, 5]) == (COMM_SUCCESS, RANGE)
    assert (rig.r1(1, 64)[0], rig.r1(1, 65)[0]) == (0, 0)
    # Goal Position beyond the limit after a valid Profile Velocity in the same packet.
    assert rig.ph.writeTxRx(rig.port, 1, 112, 8, [9, 0, 0, 0, 0xFF, 0xFF, 0, 0]) == (COMM_SUCCESS, LIMIT)
    assert rig.r4(1, 112) == (0, COMM_SUCCESS, 0)
    assert rig.ph.writeTxRx(rig.port, 1, 65, 4, [1, 0, 0, 2]) == (COMM_SUCCESS, ACCESS)  # 66/67 are gaps
    assert rig.ph.writeTxRx(rig.port, 1, 64, 2, [1, 1]) == (COMM_SUCCESS, 0)
    assert (rig.r1(1, 64)[0], rig.r1(1, 65)[0]) == (1, 1)


def test_crc_error_and_unknown_instruction(rig):
    now = rig.clock.monotonic_ns()
    bad = bytearray(p.build_instruction(1, p.PING))
    bad[-1] ^= 0x55
    status = p.parse_status(rig.bus.feed(bytes(bad), now)[0].data)
    assert status.error == CRC
    status = p.parse_status(rig.bus.feed(p.build_instruction(1, 0x7E), now + 10**6)[0].data)
    assert status.error == INSTRUCTION
    assert rig.ph.action(rig.port, BROADCAST_ID) == COMM_SUCCESS  # broadcast: silent, nothing registered


def test_silent_and_unknown_ids_time_out_boundedly(rig):
    rig.bus.set_silent(2)
    t0 = rig.clock.monotonic_ns()
    assert rig.ph.ping(rig.port, 2)[1] == COMM_RX_TIMEOUT
    assert rig.r4(2, PRESENT_POS)[1] == COMM_RX_TIMEOUT
    assert (rig.clock.monotonic_ns() - t0) / 1e6 < 80
    sr = GroupSyncRead(rig.port, rig.ph, PRESENT_POS, 4)
    for i in (1, 2, 3):
        sr.addParam(i)
    assert sr.txRxPacket() == COMM_RX_TIMEOUT
    assert sr.fastSyncRead() in (COMM_RX_CORRUPT, COMM_RX_TIMEOUT)
    assert rig.ph.broadcastPing(rig.port)[0].keys() == {1, 3}


def test_wrong_baud_makes_servos_ignore_traffic(rig):
    assert rig.port.setBaudRate(57_600)
    assert rig.ph.ping(rig.port, 1)[1] == COMM_RX_TIMEOUT
    assert rig.port.setBaudRate(1_000_000)
    assert rig.ph.ping(rig.port, 1)[1] == COMM_SUCCESS
    rig.bus[3].set_baud(57_600)
    assert rig.ph.broadcastPing(rig.port)[0].keys() == {1, 2}
    # Change a servo's baud over the bus: it answers at the old rate, then listens at the new one.
    assert rig.w1(1, 8, 1) == (COMM_SUCCESS, 0)
    assert rig.ph.ping(rig.port, 1)[1] == COMM_RX_TIMEOUT
    assert rig.port.setBaudRate(57_600)
    assert sorted(rig.ph.broadcastPing(rig.port)[0]) == [1, 3]


# ----- group instructions ------------------------------------------------------------------------------


def test_bulk_read_and_write(rig):
    bw = GroupBulkWrite(rig.port, rig.ph)
    assert bw.addParam(1, 65, 1, [1])
    assert bw.addParam(2, 112, 4, list((123).to_bytes(4, "little")))
    assert bw.addParam(3, 84, 2, [0x34, 0x12])
    assert bw.txPacket() == COMM_SUCCESS
    br = GroupBulkRead(rig.port, rig.ph)
    assert br.addParam(3, 84, 2) and br.addParam(1, 65, 1) and br.addParam(2, 112, 4)
    assert br.txRxPacket() == COMM_SUCCESS
    assert (br.getData(1, 65, 1), br.getData(2, 112, 4), br.getData(3, 84, 2)) == (1, 123, 0x1234)
    assert br.fastBulkRead() == COMM_SUCCESS
    assert (br.getData(1, 65, 1), br.getData(2, 112, 4), br.getData(3, 84, 2)) == (1, 123, 0x1234)


def test_sync_read_replies_come_in_instruction_order(rig):
    pkt = p.build_instruction(BROADCAST_ID, p.SYNC_READ, bytes((7, 0, 1, 0, 3, 1, 2)), stuffed=False)
    replies = rig.bus.feed(pkt, rig.clock.monotonic_ns())
    assert [p.parse_status(r.data).servo_id for r in replies] == [3, 1, 2]
    assert all(a.due_ns < b.due_ns for a, b in itertools.pairwise(replies))
    ping = rig.bus.feed(p.build_instruction(BROADCAST_ID, p.PING), rig.clock.monotonic_ns() + 10**7)
    assert [p.parse_status(r.data).servo_id for r in ping] == [1, 2, 3]


def test_fast_sync_read_and_firmware_gate(sdk_on_emulated_bus):
    rig = sdk_on_emulated_bus(ids=(1, 2))
    for i in (1, 2):
        rig.w4(i, 112, 10 * i)
    sr = GroupSyncRead(rig.port, rig.ph, 112, 4)
    sr.addParam(2)
    sr.addParam(1)
    assert sr.fastSyncRead() == COMM_SUCCESS
    assert (sr.getData(1, 112, 4), sr.getData(2, 112, 4)) == (10, 20)
    old = sdk_on_emulated_bus(ids=(1,), firmware=44)
    sr = GroupSyncRead(old.port, old.ph, 112, 4)
    sr.addParam(1)
    assert sr.fastSyncRead() == COMM_RX_TIMEOUT
    assert sr.txRxPacket() == COMM_SUCCESS


# ----- reg write / action, reboot, factory reset, clear --------------------------------------------------


def test_reg_write_and_action(rig):
    assert rig.ph.regWriteTxRx(rig.port, 1, 65, 1, [1]) == (COMM_SUCCESS, 0)
    assert rig.ph.regWriteTxRx(rig.port, 2, 65, 1, [1]) == (COMM_SUCCESS, 0)
    assert rig.r1(1, 69) == (1, COMM_SUCCESS, 0)
    assert rig.r1(1, 65) == (0, COMM_SUCCESS, 0)
    assert rig.ph.action(rig.port, BROADCAST_ID) == COMM_SUCCESS
    assert [rig.r1(i, 65)[0] for i in (1, 2, 3)] == [1, 1, 0]
    assert rig.r1(1, 69) == (0, COMM_SUCCESS, 0)
    # Unicast Action without a Reg Write: Instruction error. The SDK does not wait for that reply,
    # so read it straight from the bus.
    status = p.parse_status(rig.bus.feed(p.build_instruction(3, p.ACTION), rig.clock.monotonic_ns())[0].data)
    assert status.error == INSTRUCTION
    assert rig.ph.regWriteTxRx(rig.port, 1, 68, 1, [7]) == (COMM_SUCCESS, RANGE)  # validated at reg time


def test_reboot_replies_then_is_silent_then_resets_ram(rig):
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, 0)
    assert rig.w1(1, 65, 1) == (COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w4(1, GOAL_POS, 3 * 4096 + 100) == (COMM_SUCCESS, 0)
    rig.sleep(10)
    assert rig.position(1) == 3 * 4096 + 100
    t0 = rig.clock.monotonic_ns()
    assert rig.ph.reboot(rig.port, 1) == (COMM_SUCCESS, 0)
    assert rig.ph.ping(rig.port, 1)[1] == COMM_RX_TIMEOUT
    polls = 0
    while rig.ph.ping(rig.port, 1)[1] != COMM_SUCCESS:
        polls += 1
        assert polls < 100
    assert 0.25 <= (rig.clock.monotonic_ns() - t0) / 1e9 < 0.35
    assert (rig.r1(1, TORQUE)[0], rig.r1(1, 65)[0], rig.r1(1, MODE)[0]) == (0, 0, 4)  # RAM reset, EEPROM kept
    assert rig.position(1) == 100  # multi-turn count lost


def test_factory_reset_options(rig):
    assert rig.w1(2, 9, 10) == (COMM_SUCCESS, 0)
    assert rig.w1(2, 8, 3) == (COMM_SUCCESS, 0)
    assert rig.ph.factoryReset(rig.port, 2, 0x02) == (COMM_SUCCESS, 0)
    rig.sleep(0.3)
    assert rig.r1(2, 9) == (250, COMM_SUCCESS, 0)
    # 0x01 keeps the ID but resets the baud to 57600; a broadcast 0xFF is ignored.
    assert rig.ph.factoryReset(rig.port, BROADCAST_ID, 0xFF) == (COMM_SUCCESS, 0)
    rig.sleep(0.3)
    assert rig.r1(3, 7) == (3, COMM_SUCCESS, 0)
    assert rig.ph.factoryReset(rig.port, 3, 0x01) == (COMM_SUCCESS, 0)
    rig.sleep(0.3)
    assert rig.ph.ping(rig.port, 3)[1] == COMM_RX_TIMEOUT
    assert rig.bus[3].baud == 57_600
    # 0xFF resets the ID to 1 too (the reply still comes from the old ID).
    assert rig.ph.factoryReset(rig.port, 2, 0xFF) == (COMM_SUCCESS, 0)
    rig.sleep(0.3)
    assert rig.bus.ids == [1, 3]
    assert rig.ph.factoryReset(rig.port, 1, 0x07) == (COMM_SUCCESS, RANGE)


def test_clear_multi_turn(rig):
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w4(1, GOAL_POS, 5 * 4096 + 7) == (COMM_SUCCESS, 0)
    rig.sleep(0.05)
    assert rig.r1(1, 122)[0] == 1
    assert rig.ph.clearMultiTurn(rig.port, 1) == (COMM_SUCCESS, FAIL)  # moving
    rig.sleep(10)
    assert rig.ph.clearMultiTurn(rig.port, 1) == (COMM_SUCCESS, 0)
    assert rig.position(1) == 7
    assert s32(rig.r4(1, GOAL_POS)[0]) == 7  # holds where it is
    rig.sleep(1)
    assert rig.position(1) == 7


# ----- motion -----------------------------------------------------------------------------------------


def test_torque_on_holds_present_position_and_mode_change_resets(rig):
    servo = rig.bus[1]
    servo.external_torque_nm = 1.0  # back-drives the unpowered servo
    rig.sleep(0.2)
    servo.external_torque_nm = 0.0
    moved = rig.position(1)
    assert moved > 50
    assert rig.w4(1, 112, 100) == (COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert s32(rig.r4(1, GOAL_POS)[0]) == moved
    rig.sleep(1)
    assert rig.position(1) == moved
    assert rig.w1(1, TORQUE, 0) == (COMM_SUCCESS, 0)
    assert rig.w2(1, GOAL_CUR, 300) == (COMM_SUCCESS, 0)
    assert rig.w1(1, MODE, 5) == (COMM_SUCCESS, 0)
    assert rig.r4(1, 112)[0] == 0 and rig.r2(1, GOAL_CUR)[0] == 1193 and rig.r2(1, 100)[0] == 885


def test_trapezoidal_profile_timing(rig):
    # 4096 pulses at Profile Velocity 100 (22.9 rpm) and Acceleration 50 (10729 rev/min^2).
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, 0)
    assert rig.w4(1, 108, 50) == (COMM_SUCCESS, 0)
    assert rig.w4(1, 112, 100) == (COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    v = 100 * 0.229 / 60  # rev/s
    a = 50 * 214.577 / 3600  # rev/s^2
    expected_s = 1.0 / v + v / a
    assert rig.w4(1, GOAL_POS, 4096) == (COMM_SUCCESS, 0)
    rig.sleep(0.05)
    assert rig.r1(1, 123)[0] & 0x32 == 0x32  # profile running, trapezoidal
    rig.sleep(expected_s / 2 - 0.05)
    assert rig.position(1) == pytest.approx(2048, abs=30)
    vel = s32(rig.r4(1, 128)[0])
    assert vel == pytest.approx(100, abs=2)
    rig.sleep(expected_s / 2 + 0.2)
    assert rig.position(1) == 4096
    assert rig.r1(1, 122)[0] == 0 and rig.r1(1, 123)[0] & 0x01


def test_velocity_mode_and_limits(rig):
    assert rig.w1(1, MODE, 1) == (COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w4(1, 104, -100) == (COMM_SUCCESS, 0)
    rig.sleep(1.0)
    assert s32(rig.r4(1, 128)[0]) == -100
    assert rig.position(1) == pytest.approx(-100 * 0.229 / 60 * 4096, rel=0.02)


def test_present_current_follows_load_torque(rig):
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    rig.bus[1].external_torque_nm = -1.0
    rig.sleep(0.1)
    current_a = s16(rig.r2(1, PRESENT_CUR)[0]) * 0.00269
    assert current_a == pytest.approx(1.0 / XM430_W350.torque_constant_nm_per_a, abs=0.003)
    assert rig.bus[1].present_current_a == pytest.approx(1.0 / (4.1 / 2.3))


def test_mode5_stalls_against_external_torque_and_is_back_driven_beyond_the_cap(rig):
    kt = XM430_W350.torque_constant_nm_per_a
    servo = rig.bus[1]
    assert rig.w1(1, MODE, 5) == (COMM_SUCCESS, 0)
    assert rig.w2(1, GOAL_CUR, 400) == (COMM_SUCCESS, 0)  # 1.076 A -> 1.92 N m cap
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    cap_nm = 400 * 0.00269 * kt
    servo.external_torque_nm = -(cap_nm - 0.05)  # a load just under the cap, opposing positive motion
    assert rig.w4(1, GOAL_POS, 20 * 4096) == (COMM_SUCCESS, 0)
    rig.sleep(2.0)
    start = rig.position(1)
    rig.sleep(2.0)
    assert abs(rig.position(1) - start) <= 1  # stalled: cannot advance against the load
    assert s16(rig.r2(1, PRESENT_CUR)[0]) == pytest.approx(400, abs=1)
    assert rig.r1(1, 123)[0] & 0x08  # following error
    assert rig.r1(1, HW_ERR)[0] == 0  # the cap is below the Current Limit: no overload
    servo.external_torque_nm = -(cap_nm + 1.0)  # well beyond the cap: back-driven
    rig.sleep(1.0)
    assert rig.position(1) < start - 100
    servo.external_torque_nm = 0.0  # released: it winds on to the goal
    rig.sleep(60.0)
    assert rig.position(1) == 20 * 4096
    assert servo.present_position_rad == pytest.approx(20 * 2 * math.pi, abs=RAD_PER_PULSE)


def test_overload_latches_alert_torque_off_and_reboot_clears(rig):
    servo = rig.bus[1]
    assert rig.w1(1, MODE, 5) == (COMM_SUCCESS, 0)  # Goal Current = Current Limit after the mode change
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    servo.external_torque_nm = -5.0  # beyond the 3.8 N m the Current Limit allows
    rig.sleep(1.0)
    assert rig.r1(1, HW_ERR) == (0, COMM_SUCCESS, 0)
    rig.sleep(1.0)  # > 1.5 s at the limit
    value, result, error = rig.r1(1, HW_ERR)
    assert (value, result, error) == (0x20, COMM_SUCCESS, ALERT)
    assert rig.r1(1, TORQUE) == (0, COMM_SUCCESS, ALERT)  # Shutdown 0x34 includes overload
    assert rig.ph.ping(rig.port, 1)[2] == ALERT
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, ALERT | FAIL)
    servo.external_torque_nm = 0.0
    assert rig.ph.reboot(rig.port, 1) == (COMM_SUCCESS, ALERT)
    rig.sleep(0.3)
    assert rig.r1(1, HW_ERR) == (0, COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)


def test_injected_hardware_error_respects_shutdown_mask(rig):
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    rig.bus.set_hardware_error(1, 0x01)  # input voltage: not in Shutdown 0x34
    assert rig.r1(1, TORQUE) == (1, COMM_SUCCESS, ALERT)
    rig.bus.set_hardware_error(1, 0x04)  # overheating: in the mask
    assert rig.r1(1, TORQUE) == (0, COMM_SUCCESS, ALERT)
    assert rig.r1(1, HW_ERR)[0] == 0x05


def test_reply_faults_drop_corrupt_delay(rig):
    rig.bus.faults.drop_next(1)
    assert rig.ph.ping(rig.port, 1)[1] == COMM_RX_TIMEOUT
    assert rig.ph.ping(rig.port, 1)[1] == COMM_SUCCESS
    rig.bus.faults.corrupt_next(1, servo_id=2)
    assert rig.ph.ping(rig.port, 1)[1] == COMM_SUCCESS
    assert rig.ph.ping(rig.port, 2)[1] == COMM_RX_CORRUPT
    rig.bus.faults.delay_next(1, 0.05)
    assert rig.ph.ping(rig.port, 3)[1] == COMM_RX_TIMEOUT
    assert (rig.bus.faults.dropped, rig.bus.faults.corrupted, rig.bus.faults.delayed) == (1, 1, 1)


def test_world_hook_advance_is_idempotent(rig):
    rig.clock.on_advance(rig.bus.advance_to)
    rig.w1(1, MODE, 4)
    rig.w1(1, TORQUE, 1)
    rig.w4(1, GOAL_POS, 2048)
    rig.clock.advance_ns(3_000_000_000)
    pos = rig.bus[1].present_position_rad
    assert pos == pytest.approx(math.pi, abs=RAD_PER_PULSE)
    rig.bus.advance_to(rig.clock.monotonic_ns())
    rig.bus.advance_to(rig.clock.monotonic_ns() - 5)
    assert rig.bus[1].present_position_rad == pos


def test_xl430_has_no_current_mode(sdk_on_emulated_bus):
    rig = sdk_on_emulated_bus(ids=(1,), model="XL430-W250")
    assert rig.ph.ping(rig.port, 1)[0] == 1060
    assert rig.w1(1, MODE, 5) == (COMM_SUCCESS, RANGE)
    assert rig.w1(1, MODE, 16) == (COMM_SUCCESS, 0)
    assert rig.w2(1, 102, 10) == (COMM_SUCCESS, ACCESS)
    assert rig.r2(1, 100)[0] == 885


def test_indirect_addressing_reads_and_writes_through(rig):
    # Indirect Address 1..4 -> Present Position (132..135), 5..8 -> Goal Position (116..119).
    for k in range(4):
        assert rig.w2(1, 168 + 2 * k, 132 + k) == (COMM_SUCCESS, 0)
        assert rig.w2(1, 176 + 2 * k, 116 + k) == (COMM_SUCCESS, 0)
    assert rig.ph.writeTxRx(rig.port, 1, 228, 4, list((1000).to_bytes(4, "little"))) == (COMM_SUCCESS, 0)
    assert rig.r4(1, GOAL_POS)[0] == 1000
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w4(1, GOAL_POS, 1500) == (COMM_SUCCESS, 0)
    rig.sleep(3)
    assert (rig.r4(1, 224)[0], rig.r4(1, 228)[0]) == (1500, 1500)
    # Half a field through indirect data is a Data Length error.
    assert rig.ph.writeTxRx(rig.port, 1, 228, 2, [1, 2]) == (COMM_SUCCESS, LENGTH)


def test_bus_watchdog_stops_the_servo_and_blocks_goals(rig):
    assert rig.w1(1, MODE, 1) == (COMM_SUCCESS, 0)
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w1(1, 98, 5) == (COMM_SUCCESS, 0)  # 100 ms
    assert rig.w4(1, 104, 50) == (COMM_SUCCESS, 0)
    rig.sleep(0.05)
    assert s32(rig.r4(1, 128)[0]) == 50  # traffic within the window keeps it alive
    rig.sleep(0.2)  # the host went quiet
    assert rig.r1(1, 98)[0] == 0xFF
    rig.sleep(0.5)
    assert s32(rig.r4(1, 128)[0]) == 0
    assert rig.w4(1, 104, 50) == (COMM_SUCCESS, RANGE)
    assert rig.w1(1, 98, 0) == (COMM_SUCCESS, 0)
    assert rig.w4(1, 104, 50) == (COMM_SUCCESS, 0)


def test_time_based_profile_and_reverse_drive_mode(rig):
    assert rig.w1(1, 10, 0x04 | 0x01) == (COMM_SUCCESS, 0)  # time-based profile, reverse direction
    assert rig.w1(1, MODE, 4) == (COMM_SUCCESS, 0)
    assert rig.w4(1, 112, 2000) == (COMM_SUCCESS, 0)  # 2 s move
    assert rig.w4(1, 108, 500) == (COMM_SUCCESS, 0)  # 0.5 s ramps
    assert rig.w1(1, TORQUE, 1) == (COMM_SUCCESS, 0)
    assert rig.w4(1, GOAL_POS, 1024) == (COMM_SUCCESS, 0)
    rig.sleep(1.0)
    assert rig.position(1) == pytest.approx(512, abs=25)
    rig.sleep(1.2)
    assert rig.position(1) == 1024
    assert rig.bus[1].present_position_rad == pytest.approx(-math.pi / 2, abs=RAD_PER_PULSE)  # reversed
