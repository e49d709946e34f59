"""End to end in real time: `rig sim loadcell` in its own process on a pty, read through pyserial."""

import itertools
import os
import select
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import serial

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.errors import StaleDataError
from rig.hw.loadcell.calibration import Calibration, indicator_calibration
from rig.hw.loadcell.driver import SerialLoadCell
from rig.sim.loadcell.emulator import SignalModel

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")

RIG = [sys.executable, "-c", "import sys; from rig.cli import main; sys.exit(main(sys.argv[1:]))"]
DEFAULTS = SignalModel()
SIM_CAL = Calibration(
    1 / DEFAULTS.gain_counts_per_n,
    DEFAULTS.offset_counts,
    None,
    STANDARD_GRAVITY_M_S2,
    "2026-01-01",
    "",
    "rig-lc1",
)


@contextmanager
def sim_loadcell(tmp_path, *args, stop_signal=signal.SIGTERM):
    link = Path(tmp_path) / "loadcell"
    proc = subprocess.Popen(
        [*RIG, "sim", "loadcell", "--link", str(link), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        line = proc.stdout.readline() if ready else ""
        if not line.startswith("PTY "):
            proc.kill()
            pytest.fail(f"no PTY line from rig sim loadcell: {line!r} {proc.stderr.read()!r}")
        assert line.split()[1] == str(link) and link.is_symlink()
        yield link, proc
    finally:
        if proc.poll() is None:
            proc.send_signal(stop_signal)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)
        proc.stdout.close()
        proc.stderr.close()


def read_for(driver, seconds):
    samples, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        samples += driver.poll()
        time.sleep(0.01)
    return samples


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_rig_lc1_over_pyserial_then_sigterm_removes_link(tmp_path):
    with sim_loadcell(tmp_path, "--rate", "1000", "--profile", "sawtooth:20:1") as (link, proc):
        driver = SerialLoadCell(str(link), baud=921600, calibration=SIM_CAL, stale_timeout_s=0.5)
        with driver:
            assert isinstance(driver._serial, serial.Serial)  # real pyserial, reader thread
            samples = read_for(driver, 1.5)
        stats = driver.stats()
        assert 1000 <= len(samples) <= 1700  # 1.5 s at 1 kHz, with slack for a loaded machine
        seqs = [s.seq for s in samples]
        assert all(b == (a + 1) % 65536 for a, b in itertools.pairwise(seqs))
        assert (stats.corrupt_lines, stats.checksum_failures, stats.missing_samples) == (0, 0, 0)
        forces = [s.force_n for s in samples]
        assert min(forces) == pytest.approx(0.0, abs=0.05) and max(forces) == pytest.approx(20.0, abs=0.2)
        times = [s.time_ns for s in samples]
        assert times == sorted(times) and abs(times[-1] - time.time_ns()) < 1e9
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert not link.exists() and not link.is_symlink()


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_indicator_format_over_pyserial_and_sigint(tmp_path):
    args = ("--format", "indicator-st", "--rate", "100", "--baud", "115200", "--profile", "constant:12.2583")
    with sim_loadcell(tmp_path, *args, stop_signal=signal.SIGINT) as (link, proc):
        driver = SerialLoadCell(
            str(link), baud=115200, format_name="indicator-st", calibration=indicator_calibration()
        )
        with driver:
            samples = read_for(driver, 1.0)
        assert 60 <= len(samples) <= 130
        assert all(s.seq is None and s.device_time_us is None for s in samples)
        assert {s.raw for s in samples} <= {124, 125, 126}  # 12.2583 N = 1.25 kg
        assert samples[-1].force_n == pytest.approx(12.2583, abs=0.02)
        assert driver.stats().corrupt_lines == 0
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
        assert not link.is_symlink()


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_faults_from_cli_flags_are_counted(tmp_path):
    faults = (
        "--fault",
        "garbage:0.05",
        "--fault",
        "truncate:0.05",
        "--fault",
        "checksum:0.05",
        "--fault",
        "gap:0.02",
    )
    with sim_loadcell(tmp_path, "--rate", "1000", *faults) as (link, _):
        with SerialLoadCell(str(link), baud=921600, calibration=SIM_CAL) as driver:
            samples = read_for(driver, 1.0)
        stats = driver.stats()
    assert len(samples) > 600
    assert stats.corrupt_lines > 10 and stats.checksum_failures > 10 and stats.sequence_gaps > 10
    assert stats.missing_samples >= stats.corrupt_lines + stats.checksum_failures
    assert stats.bytes_discarded > 0


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_staleness_in_real_time_after_silence(tmp_path):
    with (
        sim_loadcell(tmp_path, "--rate", "1000", "--fault", "silence:1.0:1.0") as (link, _),
        SerialLoadCell(str(link), baud=921600, calibration=SIM_CAL, stale_timeout_s=0.25) as driver,
    ):
        received, raised_ns, deadline = [], None, time.monotonic() + 5.0
        while time.monotonic() < deadline:
            try:
                received += driver.poll()
            except StaleDataError:
                raised_ns = time.time_ns()
                break
            time.sleep(0.01)
        assert raised_ns is not None and received
        age_s = (raised_ns - received[-1].time_ns) / 1e9
        assert 0.25 < age_s < 0.25 + 0.5  # one poll period, plus scheduling on a shared machine
        resumed = []
        while not resumed and time.monotonic() < deadline:
            try:
                resumed = driver.poll()
            except StaleDataError:
                time.sleep(0.01)
        assert resumed
        missing = driver.stats().missing_samples
    assert 900 <= missing <= 1100  # the 1 s silence at 1 kHz, nothing else


def test_bad_flags_exit_2_without_creating_the_link(tmp_path, capsys):
    from rig.cli import main

    link = tmp_path / "lc"
    for args in (
        ["--rate", "5000"],
        ["--fault", "loud:1"],
        ["--format", "indicator-st", "--fault", "gap:0.1"],
    ):
        assert main(["sim", "loadcell", "--link", str(link), *args]) == 2
        err = capsys.readouterr().err
        assert "allowed" in err and "Traceback" not in err
        assert not os.path.lexists(link)
