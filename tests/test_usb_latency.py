"""The servo port's USB latency timer: read at connect, and named when late ticks and bus timeouts follow.

The lab's case (lab-safety issue, finding 4): with every reply held 16 ms, a run exited 0 with late
control ticks and bus timeouts, each blamed on the host. The emulated adapter's timer is written
under a stand-in sysfs root (`rig sim servos --sysfs-root`), where `rig run --sysfs-root` reads it.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from rig.errors import RigTimeoutError
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.seams import PortLatencySource
from rig.hw.usb_latency import is_slow, latency_timer_path, read_latency_timer_ms
from tests.test_hardware_path_faults import PROTOCOL  # one joint-1 trial at 0.12 m, no prompt

HOST_BLAMED = "the host did not run in time"


def test_the_timer_is_read_behind_a_by_id_link(tmp_path: Path) -> None:
    device = tmp_path / "dev" / "ttyUSB0"
    device.parent.mkdir()
    device.touch()
    by_id = tmp_path / "usb-FTDI_U2D2-if00-port0"
    by_id.symlink_to(device)
    timer = latency_timer_path(tmp_path / "sys", "ttyUSB0")
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    assert read_latency_timer_ms(str(by_id), tmp_path / "sys") == 16
    timer.write_text("garbage\n")
    assert read_latency_timer_ms(str(by_id), tmp_path / "sys") is None


@pytest.mark.parametrize("port", ["sim://servos", "socket://localhost:1", "/dev/ttyACM9"])
def test_a_port_without_a_timer_has_no_reading(tmp_path: Path, port: str) -> None:
    assert read_latency_timer_ms(port, tmp_path) is None
    assert not is_slow(None)


@pytest.mark.parametrize(("latency_ms", "named"), [(16, True), (1, False)])
def test_the_bus_reads_the_timer_at_connect_and_names_a_slow_one_in_a_timeout(
    tmp_path: Path, emulated_dxl, latency_ms: int, named: bool
) -> None:
    timer = latency_timer_path(tmp_path / "sys", "ttyUSB7")
    timer.parent.mkdir(parents=True)
    timer.write_text(f"{latency_ms}\n")
    r = emulated_dxl(ids=(1,))
    driver = DynamixelServoBus(
        str(tmp_path / "ttyUSB7"), 1_000_000, r.specs, r.clock, port_factory=r.make_port, retries=0,
        sysfs_root=tmp_path / "sys",
    )  # fmt: skip
    assert isinstance(driver, PortLatencySource) and driver.latency_timer_ms is None
    driver.connect()
    try:
        assert driver.latency_timer_ms == latency_ms
        r.bus.faults.drop_next(1)
        with pytest.raises(RigTimeoutError) as raised:
            driver.read_hardware_error(1)
        assert ("latency timer is 16 ms (set it to 1 ms" in str(raised.value)) is named
    finally:
        driver.shutdown()


@pytest.mark.pty
@pytest.mark.subprocess
@pytest.mark.slow
def test_a_16_ms_timer_is_named_at_connect_and_for_late_ticks(
    tmp_path: Path, dxl_server, loadcell_server, hardware_rig
) -> None:
    sysfs = tmp_path / "sys"
    servos = dxl_server(ids=[1, 2], extra_args=["--usb-latency-ms", "16", "--sysfs-root", str(sysfs)])
    # A constant cell: no rise, so the first ramp ends on the reel-direction check, exit 1; the
    # timer's warnings come before it. The check at 0.05 turn (default 0.25) takes about 0.8 s at
    # 0.4 rad/s instead of 4 s: some 40 control ticks, each with 16 ms holds, are plenty.
    cell = loadcell_server("constant:0.5")
    rig = hardware_rig(
        servos.link, cell.link, top={"line_stiffness_n_per_m": 20000}, limits={"direction_check_rev": 0.05}
    )
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL)
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "rig.cli",
            "run",
            str(protocol),
            "--rig",
            str(rig),
            "--out",
            str(tmp_path / "out"),
            "--sysfs-root",
            str(sysfs),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert run.returncode == 1 and "WinchDirectionError" in run.stderr, run.stderr
    notes = run.stderr.splitlines()
    connect = [n for n in notes if "latency timer is 16 ms" in n and "every servo bus transaction" in n]
    assert len(connect) == 1, run.stderr  # warned once, at connect
    assert HOST_BLAMED not in run.stderr
    late = [n for n in notes if n.startswith("control tick late") or "control ticks started late" in n]
    assert late, run.stderr  # a 16 ms hold on each of a tick's exchanges makes some ticks late
    assert all("USB latency timer is 16 ms (set it to 1 ms" in n for n in late), late
    assert all("latency timer is 16 ms" in n for n in notes if "servo bus timeouts" in n)


@pytest.mark.pty
@pytest.mark.subprocess
def test_the_emulated_adapter_follows_its_sysfs_file_as_a_udev_rule_rewrites_it(
    tmp_path: Path, dxl_server
) -> None:
    # Started at Linux's FTDI default (16 ms); then the udev rule's 1 ms is written to the file.
    sysfs = tmp_path / "sys"
    servos = dxl_server(ids=[1], extra_args=["--usb-latency-ms", "16", "--sysfs-root", str(sysfs)])
    timer = latency_timer_path(sysfs, Path(servos.pty).name)
    assert timer.read_text().strip() == "16"
    port = PortHandler(servos.link)
    assert port.openPort() and port.setBaudRate(1_000_000)
    handler = PacketHandler(2.0)

    def fastest_ping_ms() -> float:
        times = []
        for _ in range(5):
            start = time.monotonic()
            _, result, _ = handler.ping(port, 1)
            assert result == COMM_SUCCESS
            times.append((time.monotonic() - start) * 1e3)
        return min(times)

    try:
        slow = fastest_ping_ms()
        timer.write_text("1\n")
        time.sleep(0.5)  # the emulator re-reads its file at most every 0.2 s
        fast = fastest_ping_ms()
    finally:
        port.closePort()
    assert slow >= 15.0 and fast < 10.0, (slow, fast)
