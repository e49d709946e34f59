"""The firmware in the twin's loop (`rig sim rig --firmware`): the built image under simavr as its load cell.

`firmware/build/hx711-sim` (firmware/README.md) runs firmware/rig_hx711 on simavr's ATmega328P with
its HX711 model and serves the board's UART on a pty symlinked at the config's `loadcell.port`. Its
input is live (`--signal stdin`): a thread writes the counts of the world's tension every
`FEED_PERIOD_S` through the twin's signal model (gain, offset, drift, Gaussian noise: the same model
as the Python emulator's, so `--calibration-out` is the same calibration). With
`simulation.loadcell_dtr_reset_s` > 0 the board resets on every open of its port and stays silent
that long (`--reset-on-open`), as an Uno does. The image sends at the baud it was built for
(115200): a config at another baud reads garbage, as it would from the board.
"""

from __future__ import annotations

import random
import select
import subprocess
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rig.errors import ConfigError, InputError, RigError
from rig.inputs.rig_config import RigConfig
from rig.sim.loadcell.emulator import SignalModel
from rig.vocabulary import LoadCellFormatName

FEED_PERIOD_S = 0.002  # the harness reads its input every simulated millisecond
HARNESS_RATES_HZ = (10.0, 20.0, 80.0, 320.0)  # HX711 RATE pin low / high, HX717
START_TIMEOUT_S = 10.0
HARNESS_PATH = Path(__file__).resolve().parents[2] / "firmware" / "build" / "hx711-sim"


@dataclass(frozen=True)
class FirmwareCell:
    """The harness process serving the image, and where."""

    process: subprocess.Popen[str]
    link: Path
    device: str


def harness_command(harness: Path, config: RigConfig, rate_hz: float, reset_s: float) -> list[str]:
    """The harness's command line for `config`'s cell (errors naming the field the image cannot serve)."""
    if not harness.is_file():
        raise InputError(
            f"--firmware {harness}: not built; allowed: the harness `make -C firmware all sim` builds "
            "(needs gcc-avr, avr-libc, arduino-core-avr, simavr, libsimavr-dev)"
        )
    if config.loadcell.format != LoadCellFormatName.RIG_LC1:
        raise ConfigError(
            f"{config.source}: loadcell.format: {config.loadcell.format}; allowed with --firmware: rig-lc1"
        )
    if rate_hz not in HARNESS_RATES_HZ:
        raise ConfigError(
            f"{config.source}: loadcell.rate_hz: {rate_hz:g}; allowed with --firmware: 10, 80 (HX711 RATE "
            "pin), 20, 320 (HX717)"
        )
    command = [
        str(harness),
        "--link",
        str(config.loadcell.port),
        "--rate",
        f"{rate_hz:g}",
        "--signal",
        "stdin",
    ]
    if reset_s > 0:
        command += ["--reset-on-open", str(round(reset_s * 1000))]
    return command


def start_firmware_cell(command: list[str], link: Path) -> FirmwareCell:
    """Start the harness and wait for its `PTY <link> <device>` line."""
    # Its stderr (a line per banner) goes to a file: an unread pipe would fill and stall the board.
    with tempfile.TemporaryFile("w+") as errors:
        process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=errors, text=True
        )
        assert process.stdout is not None
        ready, _, _ = select.select([process.stdout], [], [], START_TIMEOUT_S)
        words = process.stdout.readline().split() if ready else []
        if len(words) >= 3 and words[0] == "PTY":
            return FirmwareCell(process, link, words[2])
        process.kill()
        process.communicate(timeout=START_TIMEOUT_S)
        errors.seek(0)
        lines = errors.read().strip().splitlines()
        message = lines[-1] if lines else "no PTY line"
        if process.returncode == 2:  # the harness refused its arguments, e.g. the link's path
            raise ConfigError(f"loadcell.port {link}: the firmware harness refused it: {message}")
        raise RigError(f"the firmware harness did not start: {message}")


def feed_firmware(
    cell: FirmwareCell,
    tension_n: Callable[[], float],
    signal: SignalModel,
    seed: int,
    stopped: Callable[[], bool],
) -> None:
    """Write the counts of the tension now to the harness every `FEED_PERIOD_S` until `stopped()`."""
    rng = random.Random(seed)
    stdin = cell.process.stdin
    assert stdin is not None
    start = time.monotonic()
    while not stopped() and cell.process.poll() is None:
        counts = signal.counts(tension_n(), time.monotonic() - start, rng.gauss(0.0, 1.0))
        try:
            stdin.write(f"{counts}\n")
            stdin.flush()
        except (BrokenPipeError, ValueError):  # the harness ended
            return
        time.sleep(FEED_PERIOD_S)


def stop_firmware_cell(cell: FirmwareCell) -> None:
    """Stop the harness (it removes its link)."""
    if cell.process.poll() is None:
        cell.process.terminate()
    try:
        cell.process.communicate(timeout=START_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        cell.process.kill()
        cell.process.communicate()
