"""The real dynamixel_sdk + pyserial against `rig sim servos` in a subprocess, over a pty.

Few, bounded checks (the SDK busy-spins a core; the machine is shared). Reads may be retried once,
as the notes say real clients must allow: every retry is counted and the count is asserted.
"""

from __future__ import annotations

import os
import signal
import time

import pytest
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

pytestmark = [pytest.mark.pty, pytest.mark.subprocess]

MAX_RETRIES_PER_TEST = 1


class Client:
    """The SDK on a port, with one counted retry for idempotent reads."""

    def __init__(self, link: str, baud: int) -> None:
        self.port = PortHandler(link)
        assert self.port.openPort()
        assert self.port.setBaudRate(baud)
        self.ph = PacketHandler(2.0)
        self.retries = 0

    def retry(self, call, ok):
        result = call()
        if not ok(result):
            self.retries += 1
            result = call()
        return result

    def close(self) -> None:
        self.port.closePort()


@pytest.mark.slow
@pytest.mark.parametrize("baud", [57_600, 1_000_000])
def test_sdk_over_pty(dxl_server, baud):
    server = dxl_server(ids=[1, 2, 3], baud=baud)
    c = Client(server.link, baud)
    try:
        ph, port = c.ph, c.port
        model, result, error = c.retry(lambda: ph.ping(port, 2), lambda r: r[1] == COMM_SUCCESS)
        assert (model, result, error) == (1020, COMM_SUCCESS, 0)

        found, result = ph.broadcastPing(port)
        assert result == COMM_SUCCESS
        assert found == {1: [1020, 48], 2: [1020, 48], 3: [1020, 48]}

        # Sync write torque on + goals in extended position mode, then read them back three ways.
        for i in (1, 2, 3):
            assert ph.write1ByteTxRx(port, i, 11, 4) == (COMM_SUCCESS, 0)
        sw = GroupSyncWrite(port, ph, 64, 1)
        for i in (1, 2, 3):
            sw.addParam(i, [1])
        assert sw.txPacket() == COMM_SUCCESS
        goals = {1: 40, 2: 80, 3: 120}
        sw = GroupSyncWrite(port, ph, 116, 4)
        for i, g in goals.items():
            sw.addParam(i, list(g.to_bytes(4, "little")))
        assert sw.txPacket() == COMM_SUCCESS

        sr = GroupSyncRead(port, ph, 116, 4)
        for i in (3, 1, 2):
            sr.addParam(i)
        assert c.retry(sr.txRxPacket, lambda r: r == COMM_SUCCESS) == COMM_SUCCESS
        assert {i: sr.getData(i, 116, 4) for i in goals} == goals

        br = GroupBulkRead(port, ph)
        assert br.addParam(1, 64, 1)
        assert br.addParam(2, 116, 4)
        assert br.addParam(3, 0, 2)
        assert c.retry(br.txRxPacket, lambda r: r == COMM_SUCCESS) == COMM_SUCCESS
        assert (br.getData(1, 64, 1), br.getData(2, 116, 4), br.getData(3, 0, 2)) == (1, 80, 1020)

        assert c.retry(sr.fastSyncRead, lambda r: r == COMM_SUCCESS) == COMM_SUCCESS
        assert {i: sr.getData(i, 116, 4) for i in goals} == goals

        # Reboot: the reply comes first, then silence for the boot period, then RAM defaults.
        assert ph.reboot(port, 2) == (COMM_SUCCESS, 0)
        assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
        deadline = time.monotonic() + 3.0
        while ph.ping(port, 2)[1] != COMM_SUCCESS:
            assert time.monotonic() < deadline, "servo 2 did not come back within 3 s of a reboot"
        assert ph.read1ByteTxRx(port, 2, 64) == (0, COMM_SUCCESS, 0)
        assert ph.read1ByteTxRx(port, 1, 64) == (1, COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 254, 64, 0) == (COMM_SUCCESS, 0)
    finally:
        c.close()
    assert c.retries <= MAX_RETRIES_PER_TEST, f"{c.retries} retries"
    print(f"retries at {baud}: {c.retries}")


def test_wrong_baud_is_silent_and_sigterm_removes_link(dxl_server):
    server = dxl_server(ids=[5, 6], baud=57_600, faults=["silent:6"])
    c = Client(server.link, 1_000_000)
    try:
        assert c.ph.ping(c.port, 5)[1] == COMM_RX_TIMEOUT  # client at 1M, servo at 57600
        assert c.port.setBaudRate(57_600)
        assert c.retry(lambda: c.ph.ping(c.port, 5), lambda r: r[1] == COMM_SUCCESS)[:2] == (
            1020,
            COMM_SUCCESS,
        )
        assert c.ph.ping(c.port, 6)[1] == COMM_RX_TIMEOUT  # --fault silent:6
    finally:
        c.close()
    assert os.path.islink(server.link)
    code, err = server.stop(signal.SIGTERM)
    assert code == 0, err
    assert not os.path.lexists(server.link)
    assert "replies" in err
    assert c.retries <= MAX_RETRIES_PER_TEST
