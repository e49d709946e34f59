"""`rig check` on a hardware-style rig config at the pty emulators (`rig sim servos`, `rig sim loadcell`).

The emulated adapter's latency timer is written under a stand-in sysfs root (`--sysfs-root`), where
`rig check --sysfs-root` reads it as it reads /sys for a real FTDI adapter.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]


# What `rig check` reads beyond the shared hardware rig (`hardware_rig`): the cell's rate and
# capacity, and a ceiling and winch current limit that pass its limit chain (rig/preflight/tension_limits.py).
CHECK_KEYS: dict[str, Any] = {
    "loadcell": {"rate_hz": 200, "capacity_n": 98},
    "limits": {"force_ceiling_n": 75, "winch_current_limit_a": 0.52},
}
# How long `rig check` listens to the cell (`--window-s`; its sections `loadcell` and `line` each
# listen this long) where no row asserted depends on the length: the shortest allowed. A check that
# must pass whole keeps the default 5 s: over 1-2 s the clock-skew row warned (1667, 2750 ppm) on the
# pty emulator, whose receipt times carry the host's scheduling.
SHORT_WINDOW = ("--window-s", "1")


def _verdicts(out: dict[str, Any]) -> dict[str, str]:
    return {row["check"]: row["verdict"] for row in out["rows"]}


def test_emulators_show_latency_voltage_and_a_loaded_line(
    tmp_path: Path,
    dxl_server: Callable[..., Any],
    loadcell_server: Callable[..., Any],
    hardware_rig: Callable[..., Path],
    run_cli: Any,
) -> None:
    sysfs = tmp_path / "sys"
    servos = dxl_server(
        ids=[1, 2], extra_args=["--usb-latency-ms", "16", "--sysfs-root", str(sysfs), "--voltage-v", "9.0"]
    )
    rig = hardware_rig(servos.link, loadcell_server("constant:8").link, **CHECK_KEYS)
    result = run_cli("check", "--rig", rig, "--sysfs-root", sysfs, *SHORT_WINDOW, "--json")
    assert result.code == 1
    rows = {row["check"]: row for row in result.data["rows"]}
    assert rows["servo bus USB latency timer"]["verdict"] == "fail"
    assert "16 ms" in rows["servo bus USB latency timer"]["measured"]
    assert rows["servo 1 (winch) input voltage"]["verdict"] == "fail"
    assert rows["line slack (load cell at its zero)"]["verdict"] == "fail"
    assert rows["load cell answers"]["verdict"] == "pass"


def test_emulators_at_1_ms_pass_then_a_missing_calibration_fails_then_a_jog_finds_no_tension(
    tmp_path: Path,
    dxl_server: Callable[..., Any],
    loadcell_server: Callable[..., Any],
    hardware_rig: Callable[..., Path],
    run_cli: Any,
) -> None:
    """Three checks on one start of the emulators (a start costs seconds on a loaded machine)."""
    sysfs = tmp_path / "sys"
    servos = dxl_server(ids=[1, 2], extra_args=["--usb-latency-ms", "1", "--sysfs-root", str(sysfs)])
    cell = loadcell_server("constant:0")

    # Every check passes (the banner may warn).
    rig = hardware_rig(servos.link, cell.link, **CHECK_KEYS)
    result = run_cli("check", "--rig", rig, "--sysfs-root", sysfs, "--json")
    verdicts = _verdicts(result.data)
    not_passed = [row for row in result.data["rows"] if row["verdict"] != "pass"]
    assert result.code == 0, not_passed
    assert verdicts["servo bus USB latency timer"] == "pass"
    assert verdicts["servos 1, 2 found"] == "pass"
    assert verdicts["line slack (load cell at its zero)"] == "pass"
    warned = {check for check, verdict in verdicts.items() if verdict != "pass"}
    assert warned <= {"banner"}, not_passed

    # Without a calibration the line check fails, naming `rig calibrate`.
    uncalibrated = hardware_rig(servos.link, cell.link, calibration=False, **CHECK_KEYS)
    result = run_cli("check", "--rig", uncalibrated, "--only", "line", *SHORT_WINDOW, "--json")
    assert result.code == 1
    (row,) = result.data["rows"]
    assert "no calibration" in row["measured"] and "rig calibrate" in row["fix"]

    # The jog on uncoupled emulators: the tension does not rise; nothing is written. The shortest
    # jog allowed (0.01 rev each way and back) shows it as well as a longer one.
    rig = hardware_rig(servos.link, cell.link, **CHECK_KEYS)
    jog = ("--move", "--jog-travel-rev", "0.01")
    result = run_cli("check", "--rig", rig, "--only", "move", *jog, *SHORT_WINDOW, "--json")
    assert result.code == 1
    row = next(r for r in result.data["rows"] if r["check"].startswith("reel direction"))
    assert row["verdict"] == "fail" and "did not rise" in row["measured"]
    assert result.data["written"] == []
