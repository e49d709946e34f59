"""The load-cell firmware as flashed: the built image runs under simavr with the HX711 model, and the
rig's own `SerialLoadCell` reads its pty (firmware/README.md).

Skipped, with the reason shown, only where the AVR toolchain or simavr's development files are not
installed (`.ci/run` installs them with apt-get); a build that fails with them present is a failure.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from rig.hw.loadcell.driver import SerialLoadCell
from rig.hw.seams import LoadCellSample
from tests.helpers import FIRMWARE, build_firmware

HARNESS = FIRMWARE / "build" / "hx711-sim"
CYCLES_PER_US = 16
MICROS_RESOLUTION_US = 4  # Arduino micros() on a 16 MHz AVR: what the format's t-us must at least meet
COUNT_MAX, COUNT_MIN = 0x7FFFFF, -0x800000


def _missing_tools() -> str | None:
    for tool in ("make", "cc", "avr-gcc", "avr-g++", "avr-objcopy", "avr-size"):
        if shutil.which(tool) is None:
            return f"{tool} not found (apt-get install gcc-avr avr-libc arduino-core-avr libsimavr-dev)"
    for header in (
        "/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h",
        "/usr/include/simavr/sim_avr.h",
    ):
        if not Path(header).exists():
            return f"{header} not found (apt-get install arduino-core-avr libsimavr-dev)"
    return None


@pytest.fixture(scope="module")
def harness() -> Path:
    """The image and the harness, built by the documented command (incremental when CI built them)."""
    missing = _missing_tools()
    if missing:
        pytest.skip(f"firmware toolchain or simavr missing: {missing}")
    build = build_firmware()
    assert build.returncode == 0, build.stdout[-2000:] + build.stderr[-2000:]
    return HARNESS


@dataclass
class Run:
    samples: list[LoadCellSample]
    info: list[str]  # information lines, as the driver received them
    stats: dict[str, float]  # the harness's own count (--stats)
    shifted: list[tuple[int, int, int]]  # (conversion, data-ready cycle, value) per read (--log)
    driver_stats: object


@contextlib.contextmanager
def _harness_process(path: Path, tmp_path: Path, *args: str) -> Iterator[tuple[subprocess.Popen[str], Path]]:
    link = tmp_path / "loadcell"
    argv = [str(path), "--fast", "--wait-open", "--link", str(link)]
    argv += ["--log", str(tmp_path / "shifted.txt"), "--stats", str(tmp_path / "stats.json"), *args]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline()
        assert ready.startswith("PTY "), ready + proc.stderr.read() if proc.stderr else ready
        yield proc, link
    finally:
        if proc.poll() is None:
            proc.terminate()
        proc.communicate(timeout=30)


def run_firmware(path: Path, tmp_path: Path, lines: int, *args: str, timeout_s: float = 60.0) -> Run:
    """Run the image until the rig's driver has read `lines` data lines, then stop it (SIGTERM).

    With --fast the harness waits for its reader when the pty is full, so a reader slowed down by a
    busy machine loses nothing; stopping it only once everything wanted is read keeps it that way.
    """
    with _harness_process(path, tmp_path, *args) as (proc, link):
        samples: list[LoadCellSample] = []
        driver = SerialLoadCell(str(link), baud=115200, stale_timeout_s=timeout_s)
        with driver:
            deadline = time.monotonic() + timeout_s
            while len(samples) < lines and time.monotonic() < deadline:
                samples += driver.poll()
                time.sleep(0.01)
            info = [line.text for line in driver.info_lines()]
            driver_stats = driver.line_stats()
        proc.terminate()
        proc.wait(timeout=30)
    samples = samples[:lines]
    stats = json.loads((tmp_path / "stats.json").read_text())
    shifted = [
        (int(a), int(b), int(c))
        for a, b, c in (row.split() for row in (tmp_path / "shifted.txt").read_text().splitlines())
    ]
    return Run(samples, info, stats, shifted, driver_stats)


def _check_every_conversion_arrives_as_shifted(run: Run, period_us: int) -> list[int]:
    """The checks every run shares; returns the raws."""
    samples, stats = run.samples, run.stats
    # Every conversion arrives: seq continuous from 0, nothing lost or damaged on the way.
    assert [s.seq for s in samples] == list(range(len(samples)))
    lines = run.driver_stats
    assert (lines.sequence_gaps, lines.missing_samples, lines.garbled_lines, lines.checksum_failures) == (
        0,
        0,
        0,
        0,
    )
    assert (lines.restarts, lines.samples_dropped) == (0, 0)
    assert stats["missed_conversions"] == 0 and stats["pty_bytes_dropped"] == 0
    assert (stats["raw_mismatches"], stats["unmatched_lines"], stats["bad_lines"]) == (0, 0, 0)  # its own tap
    # The HX711's protocol kept: 25 pulses per read (channel A, gain 128), no high phase over 50 us.
    assert (stats["serial_errors"], stats["long_high_phases"], stats["reads_other_gain"]) == (0, 0, 0)
    # Each raw is the value the model shifted out: the reads from the first one sent on (the firmware
    # times the first two conversions for its banner and does not send them).
    raws = [s.raw for s in samples]
    values = [value for _, _, value in run.shifted]
    first = next(i for i in range(len(values)) if values[i : i + len(raws)] == raws)
    assert first == 2
    # t-us is the data-ready time: its steps equal the model's, within micros() resolution.
    ready_cycles = [cycle for _, cycle, _ in run.shifted[first : first + len(raws)]]
    t_steps = [(b.device_time_us - a.device_time_us) % 2**32 for a, b in itertools.pairwise(samples)]
    ready_steps_us = [(b - a) / CYCLES_PER_US for a, b in itertools.pairwise(ready_cycles)]
    assert max(abs(t - r) for t, r in zip(t_steps, ready_steps_us, strict=True)) <= MICROS_RESOLUTION_US
    assert set(ready_steps_us) == {period_us}
    return raws


def test_every_conversion_at_80_per_s_arrives_as_shifted_out(harness, tmp_path):
    # A staircase over the whole 24-bit range and past it, twice: negative, positive and both
    # saturation codes; 5,200 samples (65 s simulated, a few seconds here).
    run = run_firmware(harness, tmp_path, 5200, "--rate", "80", "--signal", "ramp:-8389000:8404280:6720")
    assert len(run.samples) == 5200
    raws = _check_every_conversion_arrives_as_shifted(run, 12_500)
    assert min(raws) == COUNT_MIN and max(raws) == COUNT_MAX  # saturation passes through as sent
    assert raws.count(COUNT_MIN) >= 2 and raws.count(COUNT_MAX) >= 2
    assert any(-COUNT_MAX < r < 0 for r in raws) and any(0 < r < COUNT_MAX for r in raws)
    # The banner, before any sample, names the firmware, the ADC, the gain and the measured rate.
    assert run.info[0].startswith("BOOT fw=rig-hx711/")
    assert {"adc=HX711", "gain=A128", "sps=80", "period-us=12500"} <= set(run.info[0].split())
    assert run.driver_stats.info_lines == len(run.info) == 2
    assert run.stats["t_us_vs_ready_step_max_us"] <= 1  # Timer1 capture: better than micros()


def test_exact_codes_at_10_per_s_from_a_file(harness, tmp_path):
    codes = [0, -1, 1, COUNT_MAX, COUNT_MIN, COUNT_MAX + 1000, COUNT_MIN - 1000, -123456, 654321, 0x7FFFFE]
    signal_file = tmp_path / "counts.txt"
    signal_file.write_text("# counts, repeat\n" + "".join(f"{c} 1\n" for c in codes))
    n = 3 * len(codes)
    run = run_firmware(harness, tmp_path, n, "--rate", "10", "--signal", f"file:{signal_file}")
    raws = _check_every_conversion_arrives_as_shifted(run, 100_000)
    clamped = [min(max(c, COUNT_MIN), COUNT_MAX) for c in codes]
    assert raws == (clamped * 4)[2 : 2 + n]  # the file repeats; the first two went to the banner
    assert {"sps=10", "period-us=100000"} <= set(run.info[0].split())


def test_hx717_at_320_per_s_loses_nothing_at_115200_baud(harness, tmp_path):
    run = run_firmware(harness, tmp_path, 640, "--rate", "320", "--signal", "ramp:-5000:5000:7")
    _check_every_conversion_arrives_as_shifted(run, 3125)
    assert {"sps=320", "period-us=3125"} <= set(run.info[0].split())


def test_harness_refuses_bad_options_with_one_line(harness, tmp_path):
    for args in (
        ["--rate", "40"],
        ["--signal", "sine:3"],
        ["--signal", "file:/nonexistent"],
        ["--seconds", "-1"],
    ):
        done = subprocess.run([str(harness), *args], capture_output=True, text=True, timeout=10)
        assert done.returncode == 2
        assert len(done.stderr.strip().splitlines()) == 1 and done.stderr.startswith("hx711-sim: ")


@contextlib.contextmanager
def _live_harness(
    path: Path, tmp_path: Path, signal: str = "stdin"
) -> Iterator[tuple[subprocess.Popen[str], Path]]:
    """The harness in real time at 80/s, by default its input the counts written to its stdin."""
    link = tmp_path / "live"
    stats = str(tmp_path / "s.json")
    argv = [str(path), "--link", str(link), "--rate", "80", "--signal", signal, "--stats", stats]
    proc = subprocess.Popen(
        argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("PTY ")
        yield proc, link
    finally:
        proc.terminate()
        proc.communicate(timeout=30)


def _raws_until(driver: SerialLoadCell, wanted: int, timeout_s: float = 10.0) -> list[int]:
    raws: list[int] = []
    deadline = time.monotonic() + timeout_s
    while wanted not in raws[-3:] and time.monotonic() < deadline:
        raws += [s.raw for s in driver.poll()]
        time.sleep(0.01)
    return raws


@pytest.mark.pty
def test_counts_written_to_stdin_are_the_input_from_the_next_conversion(harness, tmp_path):
    # `--signal stdin`: the twin (`rig sim rig --firmware`) drives the HX711 input live.
    with _live_harness(harness, tmp_path) as (proc, link):
        assert proc.stdin is not None
        proc.stdin.write("-4321\n")
        proc.stdin.flush()
        with SerialLoadCell(str(link), baud=115200, stale_timeout_s=5.0) as driver:
            assert _raws_until(driver, -4321)[-1] == -4321
            proc.stdin.write("1234567\nnot a number\n")
            proc.stdin.flush()
            raws = _raws_until(driver, 1234567)
            time.sleep(0.1)
            raws += [s.raw for s in driver.poll()]
    assert raws[-1] == 1234567 and set(raws) <= {-4321, 1234567}  # the bad line changed nothing


@pytest.mark.pty
def test_a_client_at_another_baud_gets_garbage_as_from_a_uart(harness, tmp_path):
    # The firmware sends at 115200 (16 MHz, U2X: 117647, within 5 %); a client at 921600 would read
    # nothing but framing garbage on a real board, never a line. Before, it read the lines.
    import serial

    with _live_harness(harness, tmp_path, "constant:100") as (_, link):
        with serial.Serial(str(link), 921600, timeout=0.5) as port:
            time.sleep(0.3)
            wrong = port.read(200)
        with serial.Serial(str(link), 115200, timeout=0.5) as port:
            time.sleep(0.3)
            right = port.read(200)
    assert wrong and b"$LC" not in wrong and b"\n" not in wrong and all(b >= 0x80 for b in wrong)
    assert b"$LC," in right
    assert json.loads((tmp_path / "s.json").read_text())["wrong_baud_bytes"] > 0


@pytest.mark.pty
def test_every_open_resets_the_board_after_the_bootloaders_wait(harness, tmp_path):
    # An Uno resets on every open of its port (DTR), and optiboot waits before the sketch starts:
    # each client then reads the banner first and seq from 0, never a line of the previous boot.
    import serial

    link, stats = tmp_path / "board", tmp_path / "s.json"
    argv = [str(harness), "--link", str(link), "--rate", "80", "--signal", "constant:5"]
    proc = subprocess.Popen(
        [*argv, "--reset-on-open", "1500", "--stats", str(stats)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("PTY ")
        time.sleep(0.5)  # the board streams into the closed port meanwhile
        for _ in range(2):
            start = time.monotonic()
            with serial.Serial(str(link), 115200, timeout=4) as port:
                first = port.readline()
                waited_s = time.monotonic() - start
                port.readline()  # the #INFO line
                sample = port.readline()
            assert first.startswith(b"#BOOT fw=rig-hx711/") and sample.startswith(b"$LC,0,")
            assert 1.4 <= waited_s <= 3.0
    finally:
        proc.terminate()
        proc.communicate(timeout=30)
    assert json.loads(stats.read_text())["resets_on_open"] == 2
