"""The real dynamixel_sdk against the emulated bus over the in-process transport (virtual time)."""

from __future__ import annotations

import pytest
from dynamixel_sdk import (
    BROADCAST_ID,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
)

from rig.hw.dxl.control_table import XM430_W350
from tests.helpers import s32, u32


@pytest.fixture
def rig3(sdk_on_emulated_bus):
    rig = sdk_on_emulated_bus(ids=[1, 2, 3], model="XM430-W350", baud=1_000_000, coupled=False)
    return rig.clock, rig.bus, rig.port, rig.ph


def test_ping_reports_model_and_takes_wire_time(rig3):
    clock, _, port, ph = rig3
    t0 = clock.monotonic_ns()
    model, result, error = ph.ping(port, 2)
    assert (model, result, error) == (XM430_W350.model_number, COMM_SUCCESS, 0)
    # 10-byte ping + 500 us return delay + 14-byte status at 1 Mbps = 740 us of virtual time.
    assert clock.monotonic_ns() - t0 == 740_000


def test_missing_id_times_out_in_the_sdk_window(rig3):
    clock, _, port, ph = rig3
    t0 = clock.monotonic_ns()
    _, result, _ = ph.ping(port, 9)
    assert result == COMM_RX_TIMEOUT
    assert 34.0 < (clock.monotonic_ns() - t0) / 1e6 < 35.0


def test_sync_read_and_write_positions(rig3):
    clock, bus, port, ph = rig3
    for i in (1, 2, 3):
        assert ph.write1ByteTxRx(port, i, 11, 4) == (COMM_SUCCESS, 0)  # extended position
        assert ph.write1ByteTxRx(port, i, 64, 1) == (COMM_SUCCESS, 0)
    goals = {1: 1000, 2: -3000, 3: 50_000}
    sw = GroupSyncWrite(port, ph, 116, 4)
    for i, g in goals.items():
        assert sw.addParam(i, list(u32(g).to_bytes(4, "little")))
    assert sw.txPacket() == COMM_SUCCESS
    clock.advance_ns(20_000_000_000)
    sr = GroupSyncRead(port, ph, 132, 4)
    for i in (3, 1, 2):
        sr.addParam(i)
    assert sr.txRxPacket() == COMM_SUCCESS
    assert {i: s32(sr.getData(i, 132, 4)) for i in goals} == goals
    assert bus[3].present_position_rad == pytest.approx(50_000 * 2 * 3.141592653589793 / 4096, abs=1e-9)
    assert ph.broadcastPing(port) == ({1: [1020, 48], 2: [1020, 48], 3: [1020, 48]}, COMM_SUCCESS)
    assert ph.write1ByteTxRx(port, BROADCAST_ID, 64, 0) == (COMM_SUCCESS, 0)
