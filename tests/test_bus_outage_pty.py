"""A servo bus that goes quiet, or a host that pauses, mid-ramp: `rig run` against `rig sim servos`.

Over ptys. The servo emulator is frozen (SIGSTOP) mid-ramp, as a USB adapter that hangs: the
release keeps trying for `servos.release_patience_s`, verifies the safe state once the bus answers
and the trial is repeated; a bus silent for longer ends the run (exit 1) saying what state the
winch is in. An emulator killed outright (the adapter pulled out) is reported naming its port. The
run itself frozen for longer than the watchdog (a host pause) trips it; the run clears it.
The winch's position and torque are read back from the emulator afterwards.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.test_hardware_path_faults import (
    PRESENT_POSITION,
    PROTOCOL,
    TORQUE_ENABLE,
    UNCOUPLED_LIMITS,
    _read,
    _wait_until_ramping,
)

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]


def _start(tmp_path: Path, dxl_server, loadcell_server, hardware_rig, patience_s: float):
    servos = dxl_server(ids=[1, 2], baud=1_000_000)
    cell_server = loadcell_server("constant:0.5")
    cell = cell_server.process
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL)
    # The cell reads a constant 0.5 N: no slip and no rise, so a ramp ends on the reel-direction
    # check (half a turn, about 8 s at 0.4 rad/s) and the run measured nothing (exit 1). This nominal
    # stiffness keeps the ramp's timeout short (the default 200 N/m would allow minutes).
    rig = hardware_rig(
        servos.link,
        cell_server.link,
        servos={"release_patience_s": patience_s},
        top={"line_stiffness_n_per_m": 2000},
        limits=UNCOUPLED_LIMITS,
    )
    args = [
        "run",
        str(protocol),
        "--rig",
        str(rig),
        "--json",
        "--out",
        str(tmp_path / "out"),
        "--run-id",
        "o",
    ]
    run = subprocess.Popen(
        [sys.executable, "-m", "rig.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    _wait_until_ramping(run, tmp_path / "out" / "o.mcap")
    return servos, cell, run


def _freeze(process, seconds: float) -> None:
    """Stop a process (an emulator, or the host's run) for `seconds`, then let it go on."""
    process = getattr(process, "process", process)
    process.send_signal(signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        process.send_signal(signal.SIGCONT)


def _journal(tmp_path: Path) -> dict:
    return json.loads((tmp_path / "out" / "o.journal.json").read_text())


def _notes(tmp_path: Path) -> list[str]:
    with (tmp_path / "out" / "o.mcap").open("rb") as f:
        return [
            json.loads(m.data)["message"] for _, _, m in make_reader(f).iter_messages(topics=["/rig/log"])
        ]


def test_a_bus_quiet_for_a_second_mid_ramp_costs_a_repeated_trial(
    tmp_path, dxl_server, loadcell_server, hardware_rig
):
    servos, cell, run = _start(tmp_path, dxl_server, loadcell_server, hardware_rig, patience_s=5.0)
    try:
        _freeze(servos, 1.0)  # longer than the servos' Bus Watchdog (0.5 s): it trips on resuming
        out, _ = run.communicate(timeout=180)
    finally:
        cell.kill()
    report = json.loads(out)
    notes = _notes(tmp_path)
    # The repeated trial's ramp meets the constant cell again: the reel-direction check ends the run.
    assert run.returncode == 1 and "WinchDirectionError" in str(report["reason"]), "\n".join(
        [str(report["reason"]), *(n for n in notes if "late by" not in n)]
    )
    assert report["safe_state_verified"] is True
    # Repeated (a host stalled beyond the watchdog by a loaded machine may void it once more).
    assert _journal(tmp_path)["retried_trials"][:1] == [1], "\n".join(n for n in notes if "late by" not in n)
    assert any("Bus Watchdog tripped" in n for n in notes), notes
    link = Path(servos.link)
    _assert_slack_and_torque_off(link)


def test_a_host_paused_mid_ramp_finds_the_tripped_watchdog_clears_it_and_repeats_the_trial(
    tmp_path, dxl_server, loadcell_server, hardware_rig
):
    servos, cell, run = _start(tmp_path, dxl_server, loadcell_server, hardware_rig, patience_s=5.0)
    try:
        _freeze(run, 1.5)  # the host stops (a suspend, a slow disk); the servos' watchdog (0.5 s) trips
        out, _ = run.communicate(timeout=180)
    finally:
        cell.kill()
    report = json.loads(out)
    notes = _notes(tmp_path)
    # The repeated trial's ramp meets the constant cell again: the reel-direction check ends the run.
    assert run.returncode == 1 and "WinchDirectionError" in str(report["reason"]), "\n".join(
        [str(report["reason"]), *(n for n in notes if "late by" not in n)]
    )
    assert any("servo 1 (winch): Bus Watchdog tripped" in n and "cleared and re-armed" in n for n in notes)
    assert any(n.startswith("control tick late by") for n in notes)
    assert _journal(tmp_path)["retried_trials"][:1] == [1]
    link = Path(servos.link)
    _assert_slack_and_torque_off(link)


def test_a_bus_silent_beyond_the_patience_ends_the_run_saying_what_state_the_winch_is_in(
    tmp_path, dxl_server, loadcell_server, hardware_rig
):
    servos, cell, run = _start(tmp_path, dxl_server, loadcell_server, hardware_rig, patience_s=1.0)
    servos.process.send_signal(signal.SIGSTOP)
    try:
        out, _ = run.communicate(timeout=180)  # the run gives up while the bus is still frozen
        link = Path(servos.link)
    finally:
        servos.process.send_signal(signal.SIGCONT)
        cell.kill()
    report = json.loads(out)
    assert run.returncode == 1
    assert report["safe_state_verified"] is False
    reason = report["reason"]
    assert f"the winch has not answered on the servo bus {link}" in reason
    assert "servos.release_patience_s 1 s" in reason
    assert "their Bus Watchdog holds the winch where it was, torque on" in reason
    assert "THE LINE MAY BE LOADED" in reason


def test_a_servo_adapter_pulled_out_is_reported_naming_its_port(
    tmp_path, dxl_server, loadcell_server, hardware_rig
):
    servos, cell, run = _start(tmp_path, dxl_server, loadcell_server, hardware_rig, patience_s=5.0)
    try:
        servos.process.send_signal(signal.SIGKILL)  # the pty's other end is gone: EIO, as a pulled adapter
        out, _ = run.communicate(timeout=180)
    finally:
        cell.kill()
    report = json.loads(out)
    assert run.returncode == 1
    reason = report["reason"]
    assert "internal error" not in reason and "error(5" not in reason
    assert f"servo port {servos.link} vanished" in reason
    assert "was unplugged or lost power" in reason and "--resume" in reason
    assert report["safe_state_verified"] is False and "THE LINE MAY BE LOADED" in reason


def _read_back(link: Path, servo_id: int, address: int, size: int) -> int:
    """`_read`, tried up to three times (a loaded machine can miss the SDK's 34 ms window)."""
    for attempt in range(3):
        try:
            return _read(link, servo_id, address, size)
        except AssertionError:
            if attempt == 2:
                raise
            time.sleep(0.2)
    raise AssertionError("unreachable")


def _signed(raw: int) -> int:
    return raw - (1 << 32) if raw >= 1 << 31 else raw


def _assert_slack_and_torque_off(link: Path) -> None:
    """Read back from the emulator: both servos' torque off, the winch at its zero (line slack).

    The winch's zero is where it stood at connect (pulse 0 in the emulator).
    """
    assert [_read_back(link, i, TORQUE_ENABLE, 1) for i in (1, 2)] == [0, 0]
    assert abs(_signed(_read_back(link, 1, PRESENT_POSITION, 4))) < 30
