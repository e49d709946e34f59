"""The hardware rig over pseudo-terminals: `rig run` against `rig sim servos` and `rig sim loadcell`.

No simulated world couples the devices here (the load cell streams a constant tension), so this
checks what a real rig's run does when a device fails, in real time, through the real drivers:
the load cell's USB adapter pulled out mid-ramp must still end with the winch released by the
servos, which are healthy, and its torque off.

A constant tension is what a load cell that is not on the line reads: the run's reel-direction
check (docs/design.md §6 2d) stops such a ramp once the winch has turned
`limits.direction_check_rev`. These rigs set it to its largest, half a turn, and the protocol reels
at 0.4 rad/s, so a ramp lasts about 8 s before the check ends it: the faults below come before.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]

Process = subprocess.Popen[str]
TORQUE_ENABLE = 64
BUS_WATCHDOG = 98
PRESENT_POSITION = 132
PROTOCOL = """\
format: rig-protocol/1
name: hwpath
detector: {arm_threshold_n: 2.0, drop_fraction: 0.15}
ramp: {fast_speed_rad_s: 0.4, slow_speed_rad_s: 0.2, max_force_n: 40.0}
limits: {force_ceiling_n: 45.0}
blocks:
  - kind: joint_estimation
    joint: 1
    distances_m: [0.12]
    repeats: 1
    steps: [{tare: {settle_s: 0.2}}, ramp_until_slip, unload]
"""

# The reel-direction check at its longest (half a turn): a constant cell never shows a rise.
UNCOUPLED_LIMITS = {"direction_check_rev": 0.5}


def _start_run(tmp_path: Path, rig: Path) -> subprocess.Popen[str]:
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL)
    args = ["run", str(protocol), "--rig", str(rig), "--json", "--out", str(tmp_path / "out")]
    return subprocess.Popen(
        [sys.executable, "-m", "rig.cli", *args, "--run-id", "hw"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


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


def _wait_until_ramping(run: Process, log: Path, timeout_s: float = 60.0) -> None:
    """Wait until the run logs its ticks (connected: the watchdog armed), then 2 s more (reeling)."""
    deadline = time.monotonic() + timeout_s
    while not (log.exists() and log.stat().st_size > 20_000):  # a flushed chunk of ticks
        assert run.poll() is None, run.communicate()
        assert time.monotonic() < deadline, "the run did not start logging"
        time.sleep(0.1)
    time.sleep(2.0)
    assert run.poll() is None, run.communicate()


@contextlib.contextmanager
def _mid_ramp(
    tmp_path: Path, dxl_server, loadcell_server, hardware_rig
) -> Iterator[tuple[Path, subprocess.Popen[str], subprocess.Popen[str]]]:
    """Servos and load cell on ptys, and `rig run` on them 4 s in: the winch reeling (no slip, the
    tension is constant). Yields (servo link, load-cell process, run process); the cell is killed after."""
    servos = dxl_server(ids=[1, 2], baud=1_000_000)
    cell_server = loadcell_server("constant:0.5")
    cell = cell_server.process
    try:
        run = _start_run(tmp_path, hardware_rig(servos.link, cell_server.link, limits=UNCOUPLED_LIMITS))
        _wait_until_ramping(run, tmp_path / "out" / "hw.mcap")
        yield Path(servos.link), cell, run
    finally:
        if cell.poll() is None:
            cell.kill()
        cell.wait(timeout=10)


def test_load_cell_unplugged_mid_ramp_ends_with_the_winch_released(
    tmp_path, dxl_server, loadcell_server, hardware_rig
):
    with _mid_ramp(tmp_path, dxl_server, loadcell_server, hardware_rig) as (link, cell, run):
        cell.send_signal(signal.SIGKILL)  # the adapter is pulled out
        out, err = run.communicate(timeout=60)
    report = json.loads(out)
    assert run.returncode == 1, err
    assert report["safe_state_verified"] is True, report["reason"]
    assert "load cell" in report["reason"]
    assert [_read(link, i, TORQUE_ENABLE, 1) for i in (1, 2)] == [0, 0]


def test_a_host_killed_mid_ramp_leaves_a_winch_that_stops_by_itself(
    tmp_path, dxl_server, loadcell_server, hardware_rig
):
    # A power cut of the host: nothing on it runs any more. The winch's Bus Watchdog (500 ms here)
    # trips and it holds where it is; its goal was never more than a short lead ahead anyway.
    with _mid_ramp(tmp_path, dxl_server, loadcell_server, hardware_rig) as (link, _, run):
        run.send_signal(signal.SIGKILL)
        run.communicate(timeout=30)
        time.sleep(1.0)  # the watchdog's window, and then some
        first = _read(link, 1, PRESENT_POSITION, 4)
        time.sleep(1.0)
        second = _read(link, 1, PRESENT_POSITION, 4)
        assert _read(link, 1, BUS_WATCHDOG, 1) == 0xFF  # tripped (reads -1)
        assert abs(second - first) <= 2  # pulses: the winch is not reeling on
