"""The hardware rig over pseudo-terminals: `rig run` against `rig sim servos` and `rig sim loadcell`.

No simulated world couples the devices here (the load cell streams a constant tension), so this
checks what a real rig's run does when a device fails, in real time, through the real drivers:
the load cell's USB adapter pulled out mid-ramp must still end with the winch released by the
servos, which are healthy, and its torque off.
"""

from __future__ import annotations

import contextlib
import json
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from rig.hw.loadcell.calibration import Calibration

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]

Process = subprocess.Popen[str]
TORQUE_ENABLE = 64
BUS_WATCHDOG = 98
PRESENT_POSITION = 132
PROTOCOL = """\
format: rig-protocol/1
name: hwpath
detector: {arm_threshold_n: 2.0, drop_fraction: 0.15}
ramp: {fast_speed_rad_s: 1.0, slow_speed_rad_s: 0.5, max_force_n: 40.0}
limits: {force_ceiling_n: 45.0}
blocks:
  - kind: joint_estimation
    joint: 1
    distances_m: [0.12]
    repeats: 1
    steps: [{tare: {settle_s: 0.2}}, ramp_until_slip, unload]
"""


def _start_loadcell(link: Path) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "rig.cli", "sim", "loadcell", "--link", str(link), "--rate", "200",
           "--profile", "constant:0.5"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20)
    assert ready and proc.stdout is not None and proc.stdout.readline().startswith("PTY"), "no load cell"
    return proc


def _hardware_rig(tmp_path: Path, servo_link: Path, cell_link: Path) -> Path:
    """A hardware rig config on the two pseudo-terminals, with a calibration for the emulated cell."""
    Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-23", "pty", "rig-lc1").save(tmp_path / "cal.json")
    rig = tmp_path / "hw.yaml"
    rig.write_text(
        f"""\
kind: hardware
spool_radius_m: 0.01
servos:
  port: {servo_link}
  baud: 1000000
  watchdog_ms: 500
  ids: [{{id: 1, role: winch, model: XM430-W350}}, {{id: 2, role: bender, model: XM430-W350}}]
loadcell: {{port: {cell_link}, baud: 921600, format: rig-lc1, calibration: cal.json}}
article:
  joint_radius_m: 0.01
  segment_lengths_m: [0.03, 0.03]
  load: {{point_m: [0, 0, 0.03], direction: [0, -1, 0]}}
limits: {{force_ceiling_n: 50, winch_current_limit_a: 0.35, stale_timeout_s: 0.2, max_winch_travel_rev: 20}}
"""
    )
    return rig


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
    tmp_path: Path, dxl_server
) -> Iterator[tuple[Path, subprocess.Popen[str], subprocess.Popen[str]]]:
    """Servos and load cell on ptys, and `rig run` on them 4 s in: the winch reeling (no slip, the
    tension is constant). Yields (servo link, load-cell process, run process); the cell is killed after."""
    servos = dxl_server(ids=[1, 2], baud=1_000_000)
    cell_link = tmp_path / "loadcell"
    cell = _start_loadcell(cell_link)
    try:
        run = _start_run(tmp_path, _hardware_rig(tmp_path, Path(servos.link), cell_link))
        _wait_until_ramping(run, tmp_path / "out" / "hw.mcap")
        yield Path(servos.link), cell, run
    finally:
        if cell.poll() is None:
            cell.kill()
        cell.wait(timeout=10)


def test_load_cell_unplugged_mid_ramp_ends_with_the_winch_released(tmp_path, dxl_server):
    with _mid_ramp(tmp_path, dxl_server) as (link, cell, run):
        cell.send_signal(signal.SIGKILL)  # the adapter is pulled out
        out, err = run.communicate(timeout=60)
    report = json.loads(out)
    assert run.returncode == 1, err
    assert report["safe_state_verified"] is True, report["reason"]
    assert "load cell" in report["reason"]
    assert [_read(link, i, TORQUE_ENABLE, 1) for i in (1, 2)] == [0, 0]


def test_a_host_killed_mid_ramp_leaves_a_winch_that_stops_by_itself(tmp_path, dxl_server):
    # A power cut of the host: nothing on it runs any more. The winch's Bus Watchdog (500 ms here)
    # trips and it holds where it is; its goal was never more than a short lead ahead anyway.
    with _mid_ramp(tmp_path, dxl_server) as (link, _, run):
        run.send_signal(signal.SIGKILL)
        run.communicate(timeout=30)
        time.sleep(1.0)  # the watchdog's window, and then some
        first = _read(link, 1, PRESENT_POSITION, 4)
        time.sleep(1.0)
        second = _read(link, 1, PRESENT_POSITION, 4)
        assert _read(link, 1, BUS_WATCHDOG, 1) == 0xFF  # tripped (reads -1)
        assert abs(second - first) <= 2  # pulses: the winch is not reeling on
