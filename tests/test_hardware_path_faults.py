"""The hardware rig over pseudo-terminals: `rig run` against the rig's twin (`rig sim rig`).

The twin serves both devices of one coupled world behind a hardware config's ports, in real time,
so the winch reeling raises the tension the load cell reads, as on the rig. Its console upsets a
device's port as a person at the bench would (rig/sim/twin_ports.py). This checks what a real rig's
run does when a device fails mid-ramp, through the real drivers: the load cell's USB adapter pulled
out must still end with the winch released by the servos, which are healthy, and its torque off;
a host killed outright leaves the winch held by its Bus Watchdog. Each test ends on the twin's
truth: the line slack where the run says the state is safe, loaded where it says it may be.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from tests.conftest import TwinServer
from tests.helpers import smoke_protocol

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]

Process = subprocess.Popen[str]
TORQUE_ENABLE = 64
BUS_WATCHDOG = 98
PRESENT_POSITION = 132
# The shipped smoke protocol at one distance without the prompt, its ramp at 0.4 rad/s up to 40 N.
PROTOCOL = smoke_protocol(
    name="hwpath",
    description=None,
    ramp={"fast_speed_rad_s": 0.4, "slow_speed_rad_s": 0.4, "max_force_n": 40.0},
    limits={"force_ceiling_n": 45.0},
    block={"distances_m": [0.12], "steps": [{"tare": {"settle_s": 0.2}}, "ramp_until_slip", "unload"]},
)
# Mid-ramp: the line carries this much, past the arm threshold (the joint slips near 13 N on the twin).
MID_RAMP_N = 2.5


def protocol_file(tmp_path: Path) -> Path:
    """PROTOCOL in tmp_path (the twin's hand and the run both follow it)."""
    path = tmp_path / "p.yaml"
    path.write_text(PROTOCOL)
    return path


def start_run(tmp_path: Path, twin: TwinServer, run_id: str) -> Process:
    """`rig run PROTOCOL --rig <the twin's config> --json` into tmp_path/out."""
    args = ["run", str(protocol_file(tmp_path)), "--rig", str(twin.config), "--json",
            "--out", str(tmp_path / "out"), "--run-id", run_id]  # fmt: skip
    return subprocess.Popen(
        [sys.executable, "-m", "rig.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def run_to_mid_ramp(tmp_path: Path, hardware_twin, run_id: str, **rig: object) -> tuple[TwinServer, Process]:
    """The twin and `rig run` on it, returned once the ramp has loaded the line to MID_RAMP_N."""
    twin = hardware_twin(protocol_file(tmp_path), **rig)
    run = start_run(tmp_path, twin, run_id)
    twin.wait_for_tension(MID_RAMP_N, run)
    return twin, run


def _read(link: Path, servo_id: int, address: int, size: int) -> int:
    port = PortHandler(str(link))
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        handler = PacketHandler(2.0)
        read = {1: handler.read1ByteTxRx, 4: handler.read4ByteTxRx}[size]
        value, result, _ = read(port, servo_id, address)
        assert result == COMM_SUCCESS
        return int(value)
    finally:
        port.closePort()


def assert_released(truth: dict) -> None:
    """The twin's truth: the line slack and every servo's torque off."""
    assert truth["final_tension_n"] == 0.0, truth["final_tension_n"]
    assert truth["torque_off"] is True


def test_load_cell_unplugged_mid_ramp_ends_with_the_winch_released(tmp_path, hardware_twin):
    twin, run = run_to_mid_ramp(tmp_path, hardware_twin, "hw")
    twin.say("unplug loadcell", "unplug loadcell")  # the adapter is pulled out
    out, err = run.communicate(timeout=60)
    report = json.loads(out)
    assert run.returncode == 1, err
    assert report["safe_state_verified"] is True, report["reason"]
    assert "load cell" in report["reason"]
    assert [_read(twin.servo_link, i, TORQUE_ENABLE, 1) for i in (1, 2)] == [0, 0]
    assert not twin.cell_link.exists()  # still out: the path is gone
    assert_released(twin.stop())


def test_a_host_killed_mid_ramp_leaves_a_winch_that_stops_by_itself(tmp_path, hardware_twin):
    # A power cut of the host: nothing on it runs any more. The winch's Bus Watchdog (500 ms here)
    # trips and it holds where it is, the line loaded; its goal was never more than a short lead ahead.
    twin, run = run_to_mid_ramp(tmp_path, hardware_twin, "hw")
    run.send_signal(signal.SIGKILL)
    run.communicate(timeout=30)
    time.sleep(0.6)  # the watchdog's window, and then some
    first = _read(twin.servo_link, 1, PRESENT_POSITION, 4)
    held_n = twin.tension_n()
    time.sleep(0.5)
    second = _read(twin.servo_link, 1, PRESENT_POSITION, 4)
    assert _read(twin.servo_link, 1, BUS_WATCHDOG, 1) == 0xFF  # tripped (reads -1)
    assert abs(second - first) <= 2  # pulses: the winch is not reeling on
    truth = twin.stop()
    assert truth["torque_off"] is False  # held, torque on
    assert truth["final_tension_n"] == pytest.approx(held_n, abs=0.05) and held_n >= MID_RAMP_N
