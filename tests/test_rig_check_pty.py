"""`rig check` on a hardware-style rig config at the pty emulators (`rig sim servos`, `rig sim loadcell`).

The emulated adapter's latency timer is written under a stand-in sysfs root (`--sysfs-root`), where
`rig check --sysfs-root` reads it as it reads /sys for a real FTDI adapter.
"""

from __future__ import annotations

import select
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from rig.hw.loadcell.calibration import Calibration

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]


@pytest.fixture
def loadcell_server(tmp_path: Path) -> Iterator[Callable[[str], Path]]:
    """Factory: `rig sim loadcell` at a constant tension; returns the link. Every server is stopped."""
    processes: list[subprocess.Popen[str]] = []

    def start(profile: str) -> Path:
        link = tmp_path / f"cell{len(processes)}"
        cmd = [sys.executable, "-m", "rig.cli", "sim", "loadcell", "--link", str(link), "--rate", "200",
               "--profile", profile]  # fmt: skip
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        processes.append(proc)
        ready, _, _ = select.select([proc.stdout], [], [], 20)
        assert ready and proc.stdout is not None and proc.stdout.readline().startswith("PTY")
        return link

    yield start
    for proc in processes:
        proc.terminate()
        proc.communicate(timeout=10)


def _hardware_rig(tmp_path: Path, servo_link: str, cell_link: Path, calibration: bool = True) -> Path:
    if calibration:  # the emulated cell's nominal gain and offset
        Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-27", "pty", "rig-lc1").save(
            tmp_path / "cal.json"
        )
    rig = tmp_path / "hw.yaml"
    cal = ", calibration: cal.json" if calibration else ""
    rig.write_text(
        f"""\
kind: hardware
spool_radius_m: 0.01
servos:
  port: {servo_link}
  baud: 1000000
  watchdog_ms: 500
  ids: [{{id: 1, role: winch, model: XM430-W350}}, {{id: 2, role: bender, model: XM430-W350}}]
loadcell: {{port: {cell_link}, baud: 921600, format: rig-lc1, rate_hz: 200, capacity_n: 98{cal}}}
article:
  joint_radius_m: 0.01
  segment_lengths_m: [0.03, 0.03]
  load: {{point_m: [0, 0, 0.03], direction: [0, -1, 0]}}
limits: {{force_ceiling_n: 75, winch_current_limit_a: 0.52, stale_timeout_s: 0.2, max_winch_travel_rev: 20}}
"""
    )
    return rig


def _verdicts(out: dict[str, Any]) -> dict[str, str]:
    return {row["check"]: row["verdict"] for row in out["rows"]}


def test_emulators_at_1_ms_pass(
    tmp_path: Path, dxl_server: Callable[..., Any], loadcell_server: Callable[[str], Path], run_cli: Any
) -> None:
    sysfs = tmp_path / "sys"
    servos = dxl_server(ids=[1, 2], extra_args=["--usb-latency-ms", "1", "--sysfs-root", str(sysfs)])
    rig = _hardware_rig(tmp_path, servos.link, loadcell_server("constant:0"))
    result = run_cli("check", "--rig", rig, "--sysfs-root", sysfs, "--json")
    verdicts = _verdicts(result.data)
    not_passed = [row for row in result.data["rows"] if row["verdict"] != "pass"]
    assert result.code == 0, not_passed
    assert verdicts["servo bus USB latency timer"] == "pass"
    assert verdicts["servos 1, 2 found"] == "pass"
    assert verdicts["line slack (load cell at its zero)"] == "pass"
    warned = {check for check, verdict in verdicts.items() if verdict != "pass"}
    assert warned <= {"banner"}, not_passed


def test_emulators_show_latency_voltage_and_a_loaded_line(
    tmp_path: Path, dxl_server: Callable[..., Any], loadcell_server: Callable[[str], Path], run_cli: Any
) -> None:
    sysfs = tmp_path / "sys"
    servos = dxl_server(
        ids=[1, 2], extra_args=["--usb-latency-ms", "16", "--sysfs-root", str(sysfs), "--voltage-v", "9.0"]
    )
    rig = _hardware_rig(tmp_path, servos.link, loadcell_server("constant:8"))
    result = run_cli("check", "--rig", rig, "--sysfs-root", sysfs, "--json")
    assert result.code == 1
    rows = {row["check"]: row for row in result.data["rows"]}
    assert rows["servo bus USB latency timer"]["verdict"] == "fail"
    assert "16 ms" in rows["servo bus USB latency timer"]["measured"]
    assert rows["servo 1 (winch) input voltage"]["verdict"] == "fail"
    assert rows["line slack (load cell at its zero)"]["verdict"] == "fail"
    assert rows["load cell answers"]["verdict"] == "pass"


def test_jog_on_uncoupled_emulators_finds_no_tension_and_ends_torque_off(
    tmp_path: Path, dxl_server: Callable[..., Any], loadcell_server: Callable[[str], Path], run_cli: Any
) -> None:
    servos = dxl_server(ids=[1, 2])
    rig = _hardware_rig(tmp_path, servos.link, loadcell_server("constant:0"))
    result = run_cli("check", "--rig", rig, "--only", "move", "--move", "--jog-travel-rev", "0.05", "--json")
    assert result.code == 1
    row = next(r for r in result.data["rows"] if r["check"].startswith("reel direction"))
    assert row["verdict"] == "fail" and "did not rise" in row["measured"]
    assert result.data["written"] == []


def test_missing_calibration_fails_the_line_check(
    tmp_path: Path, dxl_server: Callable[..., Any], loadcell_server: Callable[[str], Path], run_cli: Any
) -> None:
    servos = dxl_server(ids=[1, 2])
    rig = _hardware_rig(tmp_path, servos.link, loadcell_server("constant:0"), calibration=False)
    result = run_cli("check", "--rig", rig, "--only", "line", "--json")
    assert result.code == 1
    (row,) = result.data["rows"]
    assert "no calibration" in row["measured"] and "rig calibrate" in row["fix"]
