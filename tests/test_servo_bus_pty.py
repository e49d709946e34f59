"""DynamixelServoBus with the real PortHandler and pyserial against `rig sim servos` over a pty (real time).

Few, bounded checks: the SDK busy-spins a core and the machine is shared. The driver's own retries
(counted in its stats) absorb the occasional missed window on a loaded machine.
"""

from __future__ import annotations

import math
import time

import pytest
from dynamixel_sdk import PacketHandler, PortHandler

from rig.errors import HandshakeError
from rig.hw.clock import SystemClock
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.seams import OperatingMode
from rig.inputs.rig_config import ServoSpec

pytestmark = [pytest.mark.pty, pytest.mark.subprocess]

SPECS = [ServoSpec(1, "winch", "XM430-W350"), ServoSpec(2, "bender", "XM430-W350")]


def torque_registers(link: str, baud: int, ids) -> dict[int, int]:
    port = PortHandler(link)
    assert port.openPort() and port.setBaudRate(baud)
    ph = PacketHandler(2.0)
    try:
        values = {}
        for i in ids:
            for _ in range(3):
                value, result, _ = ph.read1ByteTxRx(port, i, 64)
                if result == 0:
                    values[i] = value
                    break
        return values
    finally:
        port.closePort()


@pytest.mark.parametrize("baud", [1_000_000, 57_600])
def test_state_read_loop_over_a_pty(dxl_server, baud):
    server = dxl_server(ids=[1, 2], baud=baud)
    bus = DynamixelServoBus(server.link, baud, SPECS, SystemClock(), retries=2)
    with bus:
        assert bus.uses_fast_sync_read
        bus.set_operating_mode(1, OperatingMode.EXTENDED_POSITION, profile_velocity_rad_s=20.0)
        bus.set_torque([1, 2], True)
        bus.write_goal_positions({1: -2.0, 2: 1.0})
        positions = []
        for _ in range(40):
            states = bus.read_states()
            assert set(states) == {1, 2}
            assert all(s.hardware_error == 0 for s in states.values())
            positions.append(states[1].position_rad)
        # Velocity Limit (200 x 0.229 rpm = 4.8 rad/s) makes the 2 rad move take ~0.4 s; wait at most 3 s.
        deadline = time.monotonic() + 3.0
        while abs(positions[-1] + 2.0) > 0.01 and time.monotonic() < deadline:
            positions.append(bus.read_states()[1].position_rad)
            time.sleep(0.005)
        assert positions[-1] == pytest.approx(-2.0, abs=0.01)
        assert all(math.isfinite(p) for p in positions)
        assert bus.stats.failures == 0
    assert not bus.connected
    assert torque_registers(server.link, baud, [1, 2]) == {1: 0, 2: 0}


def test_dropped_replies_over_a_pty_are_retried(dxl_server):
    server = dxl_server(ids=[1, 2], faults=["drop:2:2"])
    bus = DynamixelServoBus(server.link, 1_000_000, SPECS, SystemClock(), retries=3)
    with bus:
        assert set(bus.read_states()) == {1, 2}
        assert bus.stats.timeouts >= 2
        assert bus.stats.recovered >= 1
        assert bus.stats.failures == 0


def test_silent_servo_over_a_pty_fails_the_handshake(dxl_server):
    server = dxl_server(ids=[1, 2], faults=["silent:2"])
    bus = DynamixelServoBus(server.link, 1_000_000, SPECS, SystemClock(), retries=0)
    with pytest.raises(HandshakeError, match=r"missing: servo 2 \(bender\)"):
        bus.connect()
    bus.shutdown()


def test_latched_hardware_error_over_a_pty_is_recovered_by_reboot(dxl_server):
    server = dxl_server(ids=[1, 2], faults=["hwerror:1:0x20"])
    bus = DynamixelServoBus(server.link, 1_000_000, SPECS, SystemClock(), retries=2)
    with bus:
        states = bus.read_states()
        assert states[1].hardware_error == 0x20 and states[2].hardware_error == 0
        bus.reboot(1)
        assert bus.read_states()[1].hardware_error == 0
        assert bus.stats.reboots == 1
