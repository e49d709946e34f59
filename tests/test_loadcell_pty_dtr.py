"""The DTR reset over a pty: `rig sim loadcell --dtr-reset-s` resets the board when a client opens the port.

pyserial asserts DTR on open, which resets an Arduino-class board: silent while it boots, then its
banner, then seq and its clock from 0. On a pty the emulator sees the open through inotify
(rig/sim/pty_port.py, Linux only). The run's boot grace (`loadcell.boot_grace_s`, 3 s by default)
must cover the silence; a grace shorter than the boot ends the wait with a StaleDataError.
"""

from __future__ import annotations

import json
import os
import pty
import select
import subprocess
import sys
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from rig.cli import main
from rig.errors import StaleDataError
from rig.hw.loadcell.driver import DEFAULT_BOOT_GRACE_S, SerialLoadCell
from rig.hw.seams import LoadCellSample
from rig.sim.pty_port import ClientEvent, ClientOpens

pytestmark = [
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys and inotify"),
    pytest.mark.pty,
    pytest.mark.subprocess,
    pytest.mark.slow,
]

RESET_S = 1.5
BANNER = "BOOT fw=rig-sim/1.0.0 adc=emulated gain=A128 sps=80 period-us=12500"


def test_opens_and_closes_of_a_pty_slave_are_seen_through_a_symlink(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    link = tmp_path / "port"
    link.symlink_to(name)
    watch = ClientOpens(name)
    try:
        assert watch.available and watch.events() == []  # our own descriptor was open before
        port = serial.Serial(str(link), 115200)
        assert watch.events() == [ClientEvent.OPENED]
        port.close()
        assert watch.events() == [ClientEvent.CLOSED]
    finally:
        watch.close()
        os.close(master)
        os.close(slave)


@pytest.fixture(scope="module")
def dtr_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """`rig sim loadcell` at 80/s, 115200 baud, resetting for `RESET_S` on every open; its link.

    One start for the module's tests: each of them opens the port, so each sees its own reset.
    """
    link = tmp_path_factory.mktemp("dtr") / "cell"
    cmd = [sys.executable, "-m", "rig.cli", "sim", "loadcell", "--link", str(link), "--rate", "80",
           "--baud", "115200", "--dtr-reset-s", str(RESET_S), "--banner",
           "--profile", "constant:1"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30)
        assert ready and proc.stdout is not None and proc.stdout.readline().startswith("PTY")
        time.sleep(0.2)  # lines stream before anyone opens the port (an open flushes them)
        yield link
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


def _read(
    driver: SerialLoadCell, seconds: float, enough: int | None = None
) -> tuple[list[LoadCellSample], float | None]:
    """Samples read for `seconds` after opening (or until `enough` came), and when the first came."""
    samples: list[LoadCellSample] = []
    start = time.monotonic()
    first_s = None
    driver.open()
    try:
        while time.monotonic() - start < seconds and (enough is None or len(samples) < enough):
            got = driver.poll()
            if got and first_s is None:
                first_s = time.monotonic() - start
            samples += got
            time.sleep(0.01)
    finally:
        driver.close()
    return samples, first_s


def test_each_open_resets_the_pty_board_and_the_default_boot_grace_covers_it(dtr_cell: Path) -> None:
    assert DEFAULT_BOOT_GRACE_S > RESET_S + 0.5  # the run's default, with room for a slow host
    for _ in range(2):  # every open resets the board, not only the first
        driver = SerialLoadCell(str(dtr_cell), baud=115200, rate_hz=80, stale_timeout_s=0.2)
        # Up to RESET_S + 1 s, or until 16 samples (0.2 s of them) came after the banner.
        samples, first_s = _read(driver, RESET_S + 1.0, enough=16)
        assert first_s is not None and RESET_S - 0.1 <= first_s <= RESET_S + 0.6
        assert samples[0].seq == 0 and samples[0].device_time_us == 0  # seq and clock from 0
        assert [s.seq for s in samples] == list(range(len(samples)))
        assert driver.banner is not None and driver.banner.text == BANNER
        assert driver.stats().restarts == 0  # the banner came before any sample of this open
    # A grace shorter than the board's boot: the first read after it is stale.
    short = SerialLoadCell(str(dtr_cell), baud=115200, rate_hz=80, stale_timeout_s=0.2, boot_grace_s=0.5)
    with pytest.raises(StaleDataError, match="boot grace"):
        _read(short, RESET_S)


def test_rig_check_on_a_hardware_config_sees_the_reset_and_the_banner(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], hardware_rig, dtr_cell: Path
) -> None:
    rig = hardware_rig(tmp_path / "no-servos", dtr_cell, loadcell={"baud": 115200, "rate_hz": 80})
    # The shortest window: the rows asserted here are of the open, not of the listening.
    code = main(["check", "--rig", str(rig), "--only", "loadcell", "--json", "--window-s", "1"])
    rows = {row["check"]: row for row in json.loads(capsys.readouterr().out)["rows"]}
    assert code == 0, rows
    assert rows["banner"]["verdict"] == "pass" and rows["banner"]["measured"] == "#" + BANNER
    answers = rows["load cell answers"]["measured"]
    first_s = float(answers.split("first sample ")[1].split(" s")[0])
    assert RESET_S - 0.1 <= first_s <= RESET_S + 0.6
