"""The serial load-cell driver: implements the `LoadCell` seam over pyserial (or any port like it).

It also implements `LineStatsSource`: `line_stats()` counts the lines decoded, garbled, failing their
checksum and missing from the sequence (`stats()` adds bytes and overloads, for diagnostics).

Information lines (rig-lc1 `#...`, e.g. the firmware's boot banner) are logged on this module's
logger and kept (`info_lines()`); they are counted, never as damage. A boot banner after a sample
means the device restarted: the driver logs a warning saying so, counts it (`restarts`), follows
the restarted sequence without counting a gap, and maps the restarted device clock afresh.

`poll()` never blocks. On a real port (a `serial.SerialBase`) a background reader thread reads
bytes as they arrive, stamps them on receipt with `clock.monotonic_ns()` (plus one epoch anchor
taken at `open()`), decodes them and feeds a bounded queue that `poll()` drains. On any other
port object (the in-process emulator, which lives in virtual time) `poll()` itself reads what is
waiting, without a thread. Staleness is never papered over: when no valid sample has arrived for
longer than `stale_timeout_s`, `poll()` raises `StaleDataError`.

Serial realities of cheap boards:
* Boot grace: opening the port of an Arduino Uno or Nano resets it (DTR), and its bootloader and
  setup keep it silent for 1-3 s. Until the first valid sample after `open()`, staleness allows
  `boot_grace_s` (default 3 s) instead of `stale_timeout_s`; a boot banner received meanwhile is
  logged as the device's start. After the first sample the stale timeout applies as usual.
* The stale timeout's default follows the rate: `default_stale_timeout_s(rate_hz)`, five sample
  periods but at least 0.2 s.
* Polled devices (a format with a poll command, `rig.vocabulary.LOADCELL_FORMAT_TRAITS`): the
  driver writes the command `rate_hz` times a second (from the reader thread, or from `poll()`
  when there is none) and each answer is one sample.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import serial

from rig.errors import InputError, NotConnectedError, StaleDataError
from rig.hw.clock import SystemClock
from rig.hw.loadcell.calibration import Calibration
from rig.hw.loadcell.device_time import DeviceClockMapper
from rig.hw.loadcell.formats import InfoLine, LineDecoder, get_codec
from rig.hw.seams import Clock, LoadCellLineStats, LoadCellSample
from rig.inputs.rig_config import default_stale_timeout_s
from rig.vocabulary import LOADCELL_FORMAT_TRAITS, LoadCellFormatName

# The baud rate the project's firmware sends at (RIG_BAUD in firmware/rig_hx711/rig_hx711.ino, the
# Makefile's BAUD; tests/test_firmware_host.py checks they agree). 115200 suits Arduino-class
# boards (FT232, CH340, 16U2 bridges) and carries 80 samples/s of rig-lc1 with room to spare (311/s
# at most); faster cells need a faster baud (`max_rate_hz`).
FIRMWARE_BAUD = 115200
DEFAULT_BAUD = FIRMWARE_BAUD
DEFAULT_STALE_TIMEOUT_S = 0.5
DEFAULT_BOOT_GRACE_S = 3.0
MAX_BOOT_GRACE_S = 30.0

DEFAULT_QUEUE_SAMPLES = 20_000  # 10 s at 2 kHz
_READ_TIMEOUT_S = 0.05  # how often the reader thread checks for close()
_READ_CHUNK_BYTES = 65536
_INFO_LINES_KEPT = 64

logger = logging.getLogger(__name__)

SerialFactory = Callable[..., Any]


def baud_and_firmware(baud: int, format_name: str) -> str:
    """A configured baud rate, with what the project's firmware sends for its rig-lc1 format.

    E.g. "921600; the project's firmware (firmware/rig_hx711) sends at 115200", for messages about
    a cell from which nothing valid came.
    """
    if format_name != LoadCellFormatName.RIG_LC1 or baud == FIRMWARE_BAUD:
        return str(baud)
    return f"{baud}; the project's firmware (firmware/rig_hx711) sends at {FIRMWARE_BAUD}"


def default_serial_factory(port: str, baudrate: int, timeout: float | None) -> serial.SerialBase:
    """Open with pyserial's `serial_for_url`: device paths and URLs such as `loop://` or `socket://host:port`."""
    return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout)


@dataclass(frozen=True, slots=True)
class LoadCellStats:
    """Counters of one driver since `open()`."""

    bytes_received: int
    lines_ok: int
    corrupt_lines: int  # malformed or truncated lines
    checksum_failures: int
    bytes_discarded: int  # bytes not part of any valid line (garbage, broken lines, partial first line)
    sequence_gaps: int  # places where the device's sequence counter skipped
    missing_samples: int  # sequence numbers never received (gaps, broken lines, silences)
    overload_lines: int  # valid lines the device flagged as overload
    samples_dropped: int  # decoded samples lost because poll() was not called for too long (queue full)
    info_lines: int = 0  # information lines (`#...`, e.g. a boot banner): neither samples nor damage
    restarts: int = 0  # boot banners after a sample: the device restarted


class SerialLoadCell:
    """A streaming serial load cell; see the module docstring for threading and staleness."""

    def __init__(
        self,
        port: str,
        *,
        baud: int = DEFAULT_BAUD,
        format_name: LoadCellFormatName = LoadCellFormatName.RIG_LC1,
        calibration: Calibration | None = None,
        stale_timeout_s: float | None = None,
        clock: Clock | None = None,
        serial_factory: SerialFactory | None = None,
        reader: Literal["auto", "thread", "poll"] = "auto",
        queue_samples: int = DEFAULT_QUEUE_SAMPLES,
        rate_hz: float | None = None,
        boot_grace_s: float = DEFAULT_BOOT_GRACE_S,
    ) -> None:
        traits = LOADCELL_FORMAT_TRAITS[get_codec(format_name).name]  # fails early on an unknown format
        if rate_hz is not None and not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise InputError(f"load cell rate_hz: {rate_hz}; allowed: > 0")
        if traits.poll_command is not None and rate_hz is None:
            raise InputError(f"load cell format {format_name} is polled: give its poll rate (rate_hz)")
        if stale_timeout_s is None:
            stale_timeout_s = DEFAULT_STALE_TIMEOUT_S if rate_hz is None else default_stale_timeout_s(rate_hz)
        if not (stale_timeout_s > 0 and math.isfinite(stale_timeout_s)):
            raise InputError(f"load cell stale_timeout_s: {stale_timeout_s}; allowed: > 0")
        if not 0 <= boot_grace_s <= MAX_BOOT_GRACE_S:
            raise InputError(f"load cell boot_grace_s: {boot_grace_s}; allowed: 0-{MAX_BOOT_GRACE_S:g}")
        if reader not in ("auto", "thread", "poll"):
            raise InputError(f"load cell reader: {reader!r}; allowed: auto, thread, poll")
        self.port = port
        self.baud = baud
        self.format_name = format_name
        self.calibration = calibration
        self.stale_timeout_s = stale_timeout_s
        self.boot_grace_s = boot_grace_s
        self.rate_hz = rate_hz
        self.poll_command = traits.poll_command
        self._poll_period_ns = round(1e9 / rate_hz) if rate_hz else 0
        self._next_poll_ns = 0
        self.polls_sent = 0
        self._first_sample_seen = False
        self.banner: InfoLine | None = None  # the latest boot banner since open()
        self.clock: Clock = clock or SystemClock()
        self._serial_factory = serial_factory or default_serial_factory
        self._reader_mode = reader
        if queue_samples < 1:
            raise InputError(f"load cell queue_samples: {queue_samples}; allowed: >= 1")
        self._queue_samples = queue_samples
        self._serial: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._queue: deque[LoadCellSample] = deque(maxlen=queue_samples)
        self._decoder = LineDecoder(get_codec(format_name))
        self._device_clock = DeviceClockMapper()
        self._samples_dropped = 0
        self._info: deque[InfoLine] = deque(maxlen=_INFO_LINES_KEPT)
        self._reader_error: BaseException | None = None
        self._anchor_ns = 0
        self._last_valid_mono_ns = 0

    # -- lifecycle --------------------------------------------------------------------------------
    def open(self) -> None:
        """Open the port, discard stale input, and start receiving."""
        if self._serial is not None:
            return
        threaded = self._reader_mode == "thread"
        try:
            ser = self._serial_factory(
                port=self.port, baudrate=self.baud, timeout=_READ_TIMEOUT_S if threaded else 0
            )
        except (serial.SerialException, OSError) as exc:
            raise NotConnectedError(
                f"load cell on {self.port} at {self.baud} baud: cannot open the port ({exc}); "
                "check the cable and `rig ports`"
            ) from None
        if self._reader_mode == "auto" and isinstance(ser, serial.SerialBase):
            threaded = True
            ser.timeout = _READ_TIMEOUT_S
        ser.reset_input_buffer()  # type: ignore[union-attr]  # every port class has it; the stubs' base not
        self._decoder = LineDecoder(self._decoder.codec)
        self._device_clock.reset()
        self._queue.clear()
        self._samples_dropped = 0
        self._info.clear()
        self._reader_error = None
        self._anchor_ns = self.clock.time_ns() - self.clock.monotonic_ns()
        self._last_valid_mono_ns = self.clock.monotonic_ns()  # staleness counts from open()
        self._first_sample_seen = False
        self.banner = None
        self._next_poll_ns = self._last_valid_mono_ns
        self.polls_sent = 0
        self._serial = ser
        if threaded:
            if self.poll_command is not None:  # wake often enough to poll on time
                ser.timeout = min(_READ_TIMEOUT_S, self._poll_period_ns / 4e9)
            self._stop.clear()
            self._thread = threading.Thread(
                target=self._read_forever, name=f"loadcell-reader {self.port}", daemon=True
            )
            self._thread.start()

    def close(self) -> None:
        """Stop the reader and close the port (idempotent)."""
        ser, self._serial = self._serial, None
        if ser is None:
            return
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            cancel = getattr(ser, "cancel_read", None)
            if cancel is not None:
                with contextlib.suppress(Exception):  # best effort: the join below bounds the wait
                    cancel()
            thread.join(timeout=2.0)
        ser.close()

    def __enter__(self) -> SerialLoadCell:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading ----------------------------------------------------------------------------------
    def poll(self) -> list[LoadCellSample]:
        """Samples received since the last call (possibly none); never blocks.

        Raises `NotConnectedError` when the port is closed or failed, and `StaleDataError` when
        no valid sample arrived for longer than `stale_timeout_s` and none is waiting.
        """
        ser = self._serial
        if ser is None:
            raise NotConnectedError(f"load cell {self.port}: not open")
        if self._thread is None:
            try:
                if self.poll_command is not None:
                    self._send_poll_if_due(ser)
                waiting = ser.in_waiting
                data = ser.read(waiting) if waiting else b""
            except (OSError, serial.SerialException) as exc:
                raise NotConnectedError(f"load cell {self.port}: reading failed: {exc}") from exc
            if data:
                self._ingest(data, self.clock.monotonic_ns())
        with self._lock:
            samples = list(self._queue)
            self._queue.clear()
        if samples:
            return samples
        if self._reader_error is not None:
            raise NotConnectedError(f"load cell {self.port}: reading failed: {self._reader_error}")
        age_s = self.last_sample_age_s
        if not self._first_sample_seen:
            if age_s > max(self.boot_grace_s, self.stale_timeout_s):
                heard = f"its banner came: {self.banner.text}" if self.banner else "nothing valid came"
                raise StaleDataError(
                    f"load cell {self.port}: no valid sample for {age_s:.3f} s after opening the port, "
                    f"beyond the boot grace of {self.boot_grace_s:g} s ({heard}); check the baud rate "
                    f"({baud_and_firmware(self.baud, self.format_name)}), the format "
                    f"({self.format_name}) and that the device streams (`rig check --only loadcell`)"
                )
        elif age_s > self.stale_timeout_s:
            raise StaleDataError(
                f"load cell {self.port}: no valid sample for {age_s:.3f} s; limit {self.stale_timeout_s:g} s"
            )
        return samples

    def _send_poll_if_due(self, ser: Any) -> None:
        """Write the poll command when its time has come (a polled format only)."""
        now_ns = self.clock.monotonic_ns()
        if now_ns < self._next_poll_ns:
            return
        assert self.poll_command is not None
        ser.write(self.poll_command)
        self.polls_sent += 1
        # On schedule; after a stall, from now (no burst of catch-up polls).
        self._next_poll_ns = max(
            self._next_poll_ns + self._poll_period_ns, now_ns + self._poll_period_ns // 2
        )

    @property
    def last_sample_age_s(self) -> float:
        """Seconds since the last valid sample was received (since `open()` if none yet)."""
        return (self.clock.monotonic_ns() - self._last_valid_mono_ns) / 1e9

    @property
    def is_stale(self) -> bool:
        """No valid sample for longer than the stale timeout (the boot grace until the first one)."""
        if not self._first_sample_seen:
            return self.last_sample_age_s > max(self.boot_grace_s, self.stale_timeout_s)
        return self.last_sample_age_s > self.stale_timeout_s

    @property
    def device_clock_skew_ppm(self) -> float:
        """The device clock's rate error the mapping has estimated (0 until it has; rig-lc1 only)."""
        return self._device_clock.skew_ppm

    @property
    def is_open(self) -> bool:
        """Whether `open()` succeeded and `close()` has not been called."""
        return self._serial is not None

    def stats(self) -> LoadCellStats:
        """A snapshot of the counters."""
        with self._lock:
            c = self._decoder.counts()
            dropped = self._samples_dropped
        return LoadCellStats(
            c.bytes_received,
            c.lines_ok,
            c.corrupt_lines,
            c.checksum_failures,
            c.bytes_discarded,
            c.sequence_gaps,
            c.missing_samples,
            c.overload_lines,
            dropped,
            c.info_lines,
            c.restarts,
        )

    def line_stats(self) -> LoadCellLineStats:
        """The line counts since `open()` (the `LineStatsSource` seam): what the runner logs per trial."""
        with self._lock:
            c = self._decoder.counts()
            dropped = self._samples_dropped
        return LoadCellLineStats(
            lines_ok=c.lines_ok,
            checksum_failures=c.checksum_failures,
            garbled_lines=c.corrupt_lines,
            missing_samples=c.missing_samples,
            sequence_gaps=c.sequence_gaps,
            samples_dropped=dropped,
            info_lines=c.info_lines,
            restarts=c.restarts,
        )

    def info_lines(self) -> list[InfoLine]:
        """The latest information lines since `open()` (up to 64), oldest first."""
        with self._lock:
            return list(self._info)

    def _ingest(self, data: bytes, receipt_mono_ns: int) -> None:
        """Decode bytes received at `receipt_mono_ns` and queue their samples."""
        time_ns = self._anchor_ns + receipt_mono_ns
        cal = self.calibration
        with self._lock:
            # The decoder's fast path: the same lines and counters as `LineDecoder.feed`, as columns.
            raws, seqs, device_times_us = self._decoder.feed_columns(data)
            info = self._decoder.take_info()
            if info:
                self._note_info(info)
            if not raws:
                return
            times_ns = self._sample_times_ns(device_times_us, time_ns, info)
            if cal is None:
                forces = [math.nan] * len(raws)
            else:
                factor, offset = cal.factor_n_per_count, cal.offset_counts
                forces = [(raw - offset) * factor for raw in raws]
            samples = list(map(LoadCellSample, times_ns, raws, forces, seqs, device_times_us))
            queue = self._queue
            overflow = len(queue) + len(samples) - self._queue_samples
            if overflow > 0:
                self._samples_dropped += overflow  # the bounded deque drops the oldest
            queue.extend(samples)
            self._last_valid_mono_ns = receipt_mono_ns
            self._first_sample_seen = True

    def _note_info(self, info: list[InfoLine]) -> None:
        """Log and keep information lines (called with the lock held)."""
        self._info.extend(info)
        for line in info:
            if line.banner:
                self.banner = line
            if line.restart:
                logger.warning(
                    "load cell %s restarted (boot banner after a sample: %s); its sequence and clock "
                    "start again, not counted as a sequence gap",
                    self.port,
                    line.text,
                )
            else:
                logger.info("load cell %s: %s", self.port, line.text)

    def _sample_times_ns(
        self, device_times_us: Sequence[int | None], time_ns: int, info: list[InfoLine]
    ) -> list[int]:
        """Host times of the samples; the device clock is mapped afresh after each restart."""
        cuts = [line.sample_index for line in info if line.restart]
        if not cuts:
            return self._device_clock.sample_times_ns(device_times_us, time_ns)
        times: list[int] = []
        bounds = zip([0, *cuts], [*cuts, len(device_times_us)], strict=True)
        for part, (lo, hi) in enumerate(bounds):
            if part:
                self._device_clock.reset()
            times += self._device_clock.sample_times_ns(device_times_us[lo:hi], time_ns)
        return times

    def _read_forever(self) -> None:
        ser, stop, clock = self._serial, self._stop, self.clock
        try:
            polled = self.poll_command is not None
            while not stop.is_set():
                if polled:
                    self._send_poll_if_due(ser)
                data = ser.read(max(1, min(ser.in_waiting, _READ_CHUNK_BYTES)))
                if data:
                    self._ingest(data, clock.monotonic_ns())
        except Exception as exc:  # reported to the caller by poll()
            if not stop.is_set():
                self._reader_error = exc
