"""The byte-level load-cell emulator core: tension -> ADC counts -> lines of a format, with faults.

Pure and transport-free: `lines_until(t_ns)` returns the lines of every sample whose time is at
or before `t_ns` on the caller's monotonic clock, so the same core serves the in-process fake
serial port (virtual time, `loadcell_serial.py`) and the pty process (real time,
`loadcell_pty.py`). The tension comes from the world: a callable `tension_n(t_monotonic_ns)`.

Signal chain (defaults: a 5 kg / 49 N S-beam cell at 2 mV/V and 5 V excitation into a 24-bit
ADC with a +-20 mV input range, sampled at 1 kHz):
    counts = offset + gain * tension + drift * t + N(0, noise), quantised, clamped to the ADC range
gain 80 000 counts/N puts the rated 49 N at about half of full scale (saturation near 103 N);
noise 400 counts RMS is about 5 mN, typical of a 24-bit converter run at 1 kSPS.
The noise is seeded: Box-Muller pairs from `random.Random(seed).random()` (`LoadCellEmulator._normal`),
the same algorithm and numbers as CPython's `random.gauss`, but with the spare of a pair kept by the
emulator, so that the rig-lc1 fast path can draw inline and continue the plain path's sequence.

Artefacts (`rig/sim/loadcell/artefacts.py`, off unless given): zero drift and wander, single-sample
spikes, mains hum and gain creep turn the tension into what the bridge reports before the white noise
above; they have their own random stream. With artefacts on, every sample takes the general path.

Faults (per-line probabilities, scheduled silences, or one-shot injections for tests):
garbage bytes before a line, a truncated line (its tail, terminator included, lost), a bad
checksum, a sequence gap (samples taken but never sent), silence (cable unplugged: the device
keeps sampling and counting, nothing is sent), a restart (rig-lc1: the boot banner again, then seq
and the device clock from 0, as the firmware in firmware/ does after a reset).

A rig-lc1 emulator given a `banner` sends it before its first line, as that firmware does at boot.

Cells as labs have them (`rig/sim/loadcell/cells.py` sets these; all off by default):
* `settling_s`: no sample before this long after power-on (an HX711 is not ready for 400 ms at
  10/s, 50 ms at 80/s after power-up), and again after `change_rate` (a rate change resets it).
* `clock_error_ppm`: the device's clock runs this fast (negative: slow); its samples come at its
  own rate, so `rate_hz x (1 + error)` in host time, and its microsecond stamps run fast too.
* `dtr_reset_s`: opening the port resets the board (an Arduino's DTR line): `host_opened` makes it
  silent this long, then it boots: the banner, seq and its clock from 0.
* A polled format (`value-unit`: its poll command in `rig.vocabulary.LOADCELL_FORMAT_TRAITS`)
  sends a line only when asked: `receive` takes the host's bytes, and each complete poll command
  is answered `POLL_RESPONSE_NS` later with the reading at that time.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.errors import InputError
from rig.hw.loadcell.formats import (
    BANNER_PREFIX,
    DEVICE_TIME_MODULUS_US,
    MAX_INFO_LINE_BYTES,
    MICRONEWTONS_PER_N,
    SEQ_MODULUS,
    DeviceReading,
    IndicatorStCodec,
    LineCodec,
    RigLc1Codec,
    ValueUnitCodec,
    get_codec,
    nmea_checksums,
)
from rig.sim.loadcell.artefacts import ArtefactModel
from rig.vocabulary import LOADCELL_FORMAT_TRAITS, UART_BITS_PER_BYTE, LoadCellFormatName

MIN_RATE_HZ = 10.0
MAX_RATE_HZ = 2000.0
BITS_PER_BYTE = UART_BITS_PER_BYTE
STANDARD_BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
                  1000000, 1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000)  # fmt: skip
DEFAULT_BAUD = 921600
DEFAULT_RATE_HZ = 1000.0
# Ranges of the signal model and the faults (`rig sim loadcell` options): finite, and small enough
# that no count or time computed from them overflows.
GAIN_RANGE_COUNTS_PER_N = (1e-3, 1e9)  # |gain|
COUNTS_LIMIT = 1e9  # |offset|, |drift per second|, noise
MAX_SILENCE_S = 1e6  # start and duration of a scheduled silence
_GARBAGE_ALPHABET = bytes(b for b in range(256) if b not in b"$\r\n")
# The emulated board's firmware name and version in its banner (`firmware_banner`).
SIM_FIRMWARE = "rig-sim/1.0.0"
MAX_CLOCK_ERROR_PPM = 50_000.0  # 5 %: far beyond a ceramic resonator's 0.5 %
MAX_SETTLING_S = 10.0
MAX_DTR_RESET_S = 10.0
# A polled gauge answers this long after the command's last byte (not from a manual: an assumption).
POLL_RESPONSE_NS = 2_000_000
_MAX_POLL_COMMAND_BYTES = 16

TensionSource = Callable[[int], float]


def firmware_banner(rate_hz: float) -> bytes:
    """The banner an emulated board streaming `rate_hz` sends at boot, in firmware/rig_hx711's form.

    `#BOOT fw=NAME/VERSION adc=ADC gain=A128 sps=RATE period-us=PERIOD` (protocols/loadcell-formats.md,
    "Information lines"), with the emulator's name and its nominal rate and period.
    """
    return (
        f"#BOOT fw={SIM_FIRMWARE} adc=emulated gain=A128 sps={round(rate_hz)} "
        f"period-us={round(1e6 / rate_hz)}\r\n"
    ).encode()


_LC1_TAILS = [b"*%02X\r\n" % checksum for checksum in range(256)]  # rig-lc1 line ends by checksum


def wrong_baud_garbage(data: bytes) -> bytes:
    """What a receiver at the wrong baud rate makes of `data`: high-bit bytes, never a line or terminator."""
    return bytes(((b * 37 + 11) & 0x7F) | 0x80 for b in data)


@dataclass(frozen=True, slots=True)
class SignalModel:
    """How line tension becomes ADC counts."""

    gain_counts_per_n: float = 80_000.0
    offset_counts: float = 120_000.0  # bridge imbalance at zero load
    drift_counts_per_s: float = 5.0  # slow thermal drift of the zero
    noise_counts: float = 400.0  # Gaussian, RMS
    quantisation_counts: int = 1  # ADC step after any internal decimation
    adc_bits: int = 24  # two's complement range [-2**(bits-1), 2**(bits-1) - 1]

    def __post_init__(self) -> None:
        for name, value, lo, hi in (
            ("gain_counts_per_n", abs(self.gain_counts_per_n), *GAIN_RANGE_COUNTS_PER_N),
            ("offset_counts", abs(self.offset_counts), 0.0, COUNTS_LIMIT),
            ("drift_counts_per_s", abs(self.drift_counts_per_s), 0.0, COUNTS_LIMIT),
            ("noise_counts", self.noise_counts, 0.0, COUNTS_LIMIT),
        ):
            if not (math.isfinite(value) and lo <= value <= hi):
                x = "|x|" if name != "noise_counts" else "x"
                flag = "--" + name.replace("_", "-")
                raise InputError(f"{flag} {getattr(self, name)}; allowed: {lo:g} <= {x} <= {hi:g}")
        if self.quantisation_counts < 1:
            raise InputError(f"load-cell quantisation_counts: {self.quantisation_counts}; allowed: >= 1")
        if not 8 <= self.adc_bits <= 32:
            raise InputError(f"load-cell adc_bits: {self.adc_bits}; allowed: 8-32")

    @property
    def adc_min(self) -> int:
        """Most negative count."""
        return -(1 << (self.adc_bits - 1))

    @property
    def adc_max(self) -> int:
        """Most positive count."""
        return (1 << (self.adc_bits - 1)) - 1

    def counts(self, tension_n: float, elapsed_s: float, noise_draw: float) -> int:
        """ADC counts for a tension at `elapsed_s` since power-on; `noise_draw` is a N(0, 1) draw."""
        value = (
            self.offset_counts
            + self.gain_counts_per_n * tension_n
            + self.drift_counts_per_s * elapsed_s
            + self.noise_counts * noise_draw
        )
        q = self.quantisation_counts
        counts = round(value / q) * q
        half_range = 1 << (self.adc_bits - 1)  # adc_max + 1 == -adc_min, without two property calls
        return min(max(counts, -half_range), half_range - 1)

    def counts_many(
        self, tensions_n: Sequence[float], elapsed_s: Sequence[float], noise_draws: Sequence[float]
    ) -> list[int]:
        """`counts` of each (tension, elapsed, draw); a fast path with the very same arithmetic.

        The object-level load cell converts a tick's samples in one call (no method call per
        sample); tests/test_sim_fast_paths.py holds it equal to `counts`.
        """
        offset, gain = self.offset_counts, self.gain_counts_per_n
        drift, noise = self.drift_counts_per_s, self.noise_counts
        q = self.quantisation_counts
        high = (1 << (self.adc_bits - 1)) - 1
        low = -high - 1
        out: list[int] = []
        for tension, elapsed, draw in zip(tensions_n, elapsed_s, noise_draws, strict=True):
            counts = round((offset + gain * tension + drift * elapsed + noise * draw) / q) * q
            out.append(low if counts < low else (high if counts > high else counts))
        return out


@dataclass(frozen=True, slots=True)
class FaultPlan:
    """Random faults per line and scheduled silences, as given on the command line."""

    garbage_per_line: float = 0.0
    truncate_per_line: float = 0.0
    bad_checksum_per_line: float = 0.0
    gap_per_line: float = 0.0
    silences_s: tuple[tuple[float, float], ...] = ()  # (start after power-on, duration)
    garbage_bytes_max: int = 16  # each garbage burst is 1..this many bytes
    gap_samples_max: int = 5  # each gap drops 1..this many samples

    def __post_init__(self) -> None:
        for name in ("garbage_per_line", "truncate_per_line", "bad_checksum_per_line", "gap_per_line"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise InputError(f"fault {name}: {p}; allowed: a probability 0-1")
        for start_s, duration_s in self.silences_s:
            if not (0 <= start_s <= MAX_SILENCE_S and 0 < duration_s <= MAX_SILENCE_S):
                raise InputError(
                    f"fault silence at {start_s} s for {duration_s} s; allowed: start 0-{MAX_SILENCE_S:g} s, "
                    f"duration > 0 and <= {MAX_SILENCE_S:g} s"
                )


FAULT_KINDS = ("garbage", "truncate", "checksum", "gap", "silence")


def parse_fault(spec: str, plan: FaultPlan) -> FaultPlan:
    """Add one `--fault` spec to `plan`: KIND:PROBABILITY, or silence:START_S:DURATION_S."""
    kind, _, rest = spec.partition(":")
    allowed = "garbage|truncate|checksum|gap:PROBABILITY_PER_LINE (0-1) or silence:START_S:DURATION_S"
    try:
        if kind == "silence":
            start_text, _, duration_text = rest.partition(":")
            silence = (float(start_text), float(duration_text))
            changes: dict[str, Any] = {"silences_s": (*plan.silences_s, silence)}
        else:
            name = {
                "garbage": "garbage_per_line",
                "truncate": "truncate_per_line",
                "checksum": "bad_checksum_per_line",
                "gap": "gap_per_line",
            }[kind]
            changes = {name: float(rest)}
    except (KeyError, ValueError):
        raise InputError(f"--fault {spec!r}; allowed: {allowed}") from None
    try:
        return replace(plan, **changes)
    except InputError as exc:
        raise InputError(f"--fault {spec!r}: {exc}") from None


@dataclass(slots=True)
class EmulatorCounts:
    """What the emulator did, for comparing with what the host counted."""

    samples: int = 0  # samples taken (seq advanced)
    lines_sent: int = 0  # intact lines sent
    garbage_bytes: int = 0
    truncated_lines: int = 0
    bad_checksums: int = 0
    gap_samples: int = 0  # samples dropped by sequence gaps
    silenced_samples: int = 0
    overload_lines: int = 0
    banners: int = 0  # boot banners sent (at start and at each restart)
    polls: int = 0  # poll commands received (polled formats)
    unknown_commands: int = 0  # other commands received, ignored


@dataclass(slots=True)
class _Pending:
    garbage_bytes: list[int] = field(default_factory=list)
    truncate: int = 0
    bad_checksum: int = 0
    gap_samples: int = 0
    silence_until_ns: int = -1
    banner: bool = False  # send the banner before the next line
    restart: bool = False  # ... and restart seq and the device clock at 0 with it
    boot_at_ns: int = 0  # ... not before this time (a DTR reset's silence)


class LoadCellEmulator:
    """A streaming load cell: samples `tension_n` at `rate_hz` and encodes lines in `format_name`."""

    def __init__(
        self,
        tension_n: TensionSource,
        *,
        format_name: LoadCellFormatName = LoadCellFormatName.RIG_LC1,
        rate_hz: float = DEFAULT_RATE_HZ,
        baud: int = DEFAULT_BAUD,
        signal: SignalModel | None = None,
        faults: FaultPlan | None = None,
        seed: int = 0,
        start_ns: int = 0,
        seq_start: int = 0,
        device_time_start_us: int = 0,
        indicator_g: float = STANDARD_GRAVITY_M_S2,
        artefacts: ArtefactModel | None = None,
        banner: bytes | None = None,
        codec: LineCodec | None = None,
        settling_s: float = 0.0,
        clock_error_ppm: float = 0.0,
        dtr_reset_s: float = 0.0,
    ) -> None:
        if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
            raise InputError(f"--rate {rate_hz:g} Hz; allowed: {MIN_RATE_HZ:g}-{MAX_RATE_HZ:g}")
        if baud not in STANDARD_BAUDS:
            raise InputError(f"--baud {baud}; allowed: {', '.join(map(str, STANDARD_BAUDS))}")
        for flag, value, limit in (
            ("--clock-error-ppm", abs(clock_error_ppm), MAX_CLOCK_ERROR_PPM),
            ("--settling-s", settling_s, MAX_SETTLING_S),
            ("--dtr-reset-s", dtr_reset_s, MAX_DTR_RESET_S),
        ):
            if not (math.isfinite(value) and 0 <= value <= limit):
                raise InputError(f"{flag} {value:g}; allowed: 0-{limit:g} (magnitude)")
        self.codec: LineCodec = codec if codec is not None else get_codec(format_name)
        if self.codec.name != format_name:
            raise InputError(f"load-cell codec {self.codec.name} for format {format_name}")
        self.format_name = format_name
        traits = LOADCELL_FORMAT_TRAITS[format_name]
        self.poll_command = traits.poll_command
        needed_baud = rate_hz * self.codec.max_line_bytes * BITS_PER_BYTE
        if rate_hz > traits.max_rate_hz(baud):
            raise InputError(
                f"--rate {rate_hz:g} Hz of {format_name} lines (up to {self.codec.max_line_bytes} bytes) "
                f"needs >= {needed_baud:.0f} baud; --baud {baud}; allowed: a faster baud or a lower rate"
            )
        if banner is not None and not (
            self.codec.has_info_lines
            and banner.startswith(BANNER_PREFIX)
            and banner.endswith(b"\r\n")
            and len(banner) <= MAX_INFO_LINE_BYTES
        ):
            raise InputError(
                f"load-cell banner {banner!r}; allowed: a rig-lc1 line `#BOOT ...` CR LF of at most "
                f"{MAX_INFO_LINE_BYTES} bytes"
            )
        self.banner = banner
        self.faults = faults or FaultPlan()
        self.unplugged = False  # the cable is out: the host's port fails (in-process transport)
        if not self.codec.has_checksum and self.faults.bad_checksum_per_line:
            raise InputError(f"--fault checksum: format {format_name} has no checksum; allowed with rig-lc1")
        if not self.codec.has_sequence and self.faults.gap_per_line:
            raise InputError(
                f"--fault gap: format {format_name} has no sequence counter; allowed with rig-lc1"
            )
        self.tension_n = tension_n
        self.artefacts = artefacts
        self.rate_hz = float(rate_hz)
        self.baud = baud
        self.signal = signal or SignalModel()
        self.start_ns = start_ns
        self.settling_s = settling_s
        self.clock_error_ppm = clock_error_ppm
        self.dtr_reset_s = dtr_reset_s
        self._clock_factor = 1.0 + clock_error_ppm * 1e-6
        # Sample k is taken at base_ns + (k - base_k) periods of the device's clock.
        self._base_ns = start_ns + round(settling_s * 1e9)
        self._base_k = 0
        self._period_ns = 1e9 / (self.rate_hz * self._clock_factor) if clock_error_ppm else 1e9 / self.rate_hz
        self._polls_ns: list[int] = []  # when each poll received is to be answered
        self._command = b""  # a poll command still arriving
        self.counts = EmulatorCounts()
        self._rng = random.Random(seed)
        self._spare_normal: float | None = None  # the second draw of the last Box-Muller pair
        self._k = 0  # index of the next sample
        self._seq = seq_start
        self._device_time_start_us = device_time_start_us
        self._pending = _Pending(banner=banner is not None)
        self._silences_ns = sorted(
            (start_ns + round(s * 1e9), start_ns + round((s + d) * 1e9)) for s, d in self.faults.silences_s
        )
        # indicator-st: the indicator shows kg through its own calibration, zeroed at power-on.
        self._indicator = self.codec if isinstance(self.codec, IndicatorStCodec) else None
        if self._indicator is not None:
            digits_per_n = 10.0**self._indicator.decimals / indicator_g
            self._display_per_count = digits_per_n / self.signal.gain_counts_per_n
        self._recent_display: list[int] = []
        # rig-lc1 with no random faults: samples before any silence or injected fault take a fast path.
        self._fault_free_lc1 = (
            isinstance(self.codec, RigLc1Codec)
            and artefacts is None
            and not clock_error_ppm
            and not (
                self.faults.garbage_per_line
                or self.faults.truncate_per_line
                or self.faults.bad_checksum_per_line
                or self.faults.gap_per_line
            )
        )

    # -- one-shot injections (tests) --------------------------------------------------------------
    def inject_garbage(self, n_bytes: int) -> None:
        """Send `n_bytes` random bytes (never `$`, CR or LF) before the next line."""
        self._pending.garbage_bytes.append(n_bytes)

    def inject_truncated(self, count: int = 1) -> None:
        """Cut the next `count` lines short (their tail and terminator are lost)."""
        self._pending.truncate += count

    def inject_bad_checksum(self, count: int = 1) -> None:
        """Send the next `count` lines with a wrong checksum."""
        if not self.codec.has_checksum:
            raise InputError(f"format {self.format_name} has no checksum to corrupt")
        self._pending.bad_checksum += count

    def inject_sequence_gap(self, n_samples: int) -> None:
        """Drop the next `n_samples` samples (taken and counted by the device, never sent)."""
        self._pending.gap_samples += n_samples

    def inject_restart(self) -> None:
        """Restart before the next sample: the banner (`firmware_banner` if none), seq and clock from 0."""
        if not self.codec.has_info_lines:
            raise InputError(f"format {self.format_name} has no information lines to announce a restart")
        self._pending.banner = self._pending.restart = True

    def inject_silence(self, duration_s: float, at_ns: int | None = None) -> None:
        """Send nothing for `duration_s` from `at_ns` (default: the next sample), as if unplugged."""
        start = self.sample_time_ns(self._k) if at_ns is None else at_ns
        self._silences_ns.append((start, start + round(duration_s * 1e9)))
        self._silences_ns.sort()

    # -- sampling ---------------------------------------------------------------------------------
    def sample_time_ns(self, k: int) -> int:
        """Monotonic time of sample `k` (of a streaming device)."""
        if self._clock_factor != 1.0:
            return self._base_ns + round((k - self._base_k) * self._period_ns)
        return self._base_ns + round((k - self._base_k) * 1e9 / self.rate_hz)

    @property
    def next_sample_ns(self) -> int:
        """When the next line is due (a polled device with no poll waiting: far in the future)."""
        if self.poll_command is not None:
            return self._polls_ns[0] if self._polls_ns else self._base_ns + (1 << 62)
        return self.sample_time_ns(self._k)

    def change_rate(self, rate_hz: float, at_ns: int) -> None:
        """Switch to `rate_hz` at `at_ns` (an HX711's RATE pin): no sample until it has settled again."""
        if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
            raise InputError(f"rate {rate_hz:g} Hz; allowed: {MIN_RATE_HZ:g}-{MAX_RATE_HZ:g}")
        self.lines_until(at_ns - 1)
        self.rate_hz = float(rate_hz)
        self._period_ns = 1e9 / (self.rate_hz * self._clock_factor)
        self._base_ns = at_ns + round(self.settling_s * 1e9)
        self._base_k = self._k

    def host_opened(self, t_ns: int) -> None:
        """The host opened the port at `t_ns`: with `dtr_reset_s`, the board resets and reboots."""
        if self.dtr_reset_s <= 0:
            return
        self.lines_until(t_ns)
        boot_ns = t_ns + round(self.dtr_reset_s * 1e9)
        self._silences_ns.append((t_ns, boot_ns))
        self._silences_ns.sort()
        pending = self._pending
        pending.banner = pending.restart = self.codec.has_info_lines
        pending.boot_at_ns = boot_ns
        self._polls_ns = [t for t in self._polls_ns if t < t_ns]
        if self.poll_command is None:  # the ADC restarts too: settling from the boot
            self._base_ns = boot_ns + round(self.settling_s * 1e9)
            self._base_k = self._k

    def receive(self, data: bytes, t_ns: int) -> None:
        """Bytes the host wrote, complete at `t_ns`: a polled device answers each poll command."""
        command = self.poll_command
        if command is None:
            return
        buffered = self._command + data
        *complete, self._command = buffered.replace(b"\n", b"\r").split(b"\r")
        self._command = self._command[-_MAX_POLL_COMMAND_BYTES:]
        silent = bool(self._silences_ns) and self._silenced(t_ns)
        for text in complete:
            if not text:
                continue
            if text + b"\r" == command and not silent:
                self.counts.polls += 1
                self._polls_ns.append(t_ns + POLL_RESPONSE_NS)
            else:
                self.counts.unknown_commands += 1

    def lines_until(self, t_ns: int) -> list[tuple[int, bytes]]:
        """(sample time, bytes) for every sample taken at or before `t_ns` and not yet produced."""
        out: list[tuple[int, bytes]] = []
        if self.poll_command is not None:
            polls = self._polls_ns
            while polls and polls[0] <= t_ns:
                t_answer = polls.pop(0)
                data = self._sample(t_answer)
                if data:
                    out.append((t_answer, data))
            return out
        fast = self._fault_free_lc1
        while True:
            if fast and not self._pending_faults():
                # Up to the next silence (the general path below handles it and pops it when over).
                silences = self._silences_ns
                self._lc1_lines_until(min(t_ns, silences[0][0] - 1) if silences else t_ns, out)
            t_sample = self.sample_time_ns(self._k)
            if t_sample > t_ns:
                return out
            data = self._sample(t_sample)
            if data:
                out.append((t_sample, data))

    def _normal(self) -> float:
        """A N(0, 1) noise draw (Box-Muller; the second of each pair is kept for the next call)."""
        spare = self._spare_normal
        if spare is not None:
            self._spare_normal = None
            return spare
        uniform = self._rng.random
        angle = uniform() * math.tau
        radius = math.sqrt(-2.0 * math.log(1.0 - uniform()))
        self._spare_normal = math.sin(angle) * radius
        return math.cos(angle) * radius

    def _pending_faults(self) -> bool:
        pending = self._pending
        return bool(
            pending.garbage_bytes
            or pending.truncate
            or pending.bad_checksum
            or pending.gap_samples
            or pending.banner
        )

    def _lc1_lines_until(self, t_ns: int, out: list[tuple[int, bytes]]) -> None:
        """`_sample` for every sample up to `t_ns`, for rig-lc1 with no fault due.

        The same lines, counters and random draws, with `SignalModel.counts`, `RigLc1Codec.encode` and
        `_normal` inlined and no per-sample objects.
        """
        signal = self.signal
        offset, gain = signal.offset_counts, signal.gain_counts_per_n
        drift, noise, q = signal.drift_counts_per_s, signal.noise_counts, signal.quantisation_counts
        lowest, highest = signal.adc_min, signal.adc_max
        start_ns, rate_hz, time0_us = self.start_ns, self.rate_hz, self._device_time_start_us
        base_ns, base_k = self._base_ns, self._base_k
        tension_n = self.tension_n
        times: list[int] = []
        bodies: list[bytes] = []
        add_time, add_body = times.append, bodies.append
        rng = self._rng
        uniform, tau, sqrt, log, cos, sin = rng.random, math.tau, math.sqrt, math.log, math.cos, math.sin
        spare = self._spare_normal  # `_normal` inlined, its spare in a local until the loop ends
        k = k0 = self._k
        seq = self._seq
        try:
            while True:
                t_sample = base_ns + round((k - base_k) * 1e9 / rate_hz)
                if t_sample > t_ns:
                    break
                elapsed_ns = t_sample - start_ns
                tension = tension_n(t_sample)
                if spare is None:
                    angle = uniform() * tau
                    radius = sqrt(-2.0 * log(1.0 - uniform()))
                    draw = cos(angle) * radius
                    spare = sin(angle) * radius
                else:
                    draw, spare = spare, None
                value = offset + gain * tension + drift * (elapsed_ns / 1e9) + noise * draw
                counts = round(value / q) * q
                if counts > highest:
                    counts = highest
                elif counts < lowest:
                    counts = lowest
                add_time(t_sample)
                add_body(
                    b"LC,%d,%d,%d"
                    % (seq % SEQ_MODULUS, (time0_us + elapsed_ns // 1000) % DEVICE_TIME_MODULUS_US, counts)
                )
                k += 1
                seq += 1
            # The checksums of all the bodies at once, then the lines: `RigLc1Codec.encode`'s bytes.
            tails = map(_LC1_TAILS.__getitem__, nmea_checksums(bodies))
            out.extend(zip(times, map(b"$%b%b".__mod__, zip(bodies, tails, strict=True)), strict=True))
        finally:  # also when the tension source raises: the samples made so far count
            self._spare_normal = spare
            self._k, self._seq = k, seq
            self.counts.samples += k - k0
            self.counts.lines_sent += k - k0

    def _silenced(self, t_ns: int) -> bool:
        while self._silences_ns and self._silences_ns[0][1] <= t_ns:
            self._silences_ns.pop(0)
        return bool(self._silences_ns) and self._silences_ns[0][0] <= t_ns

    def _sample(self, t_ns: int) -> bytes:
        """The bytes sent for the sample at `t_ns`: a pending banner, then the line with its faults.

        On a restart, seq and the device clock start again at 0 with this sample.
        """
        pending = self._pending
        if not pending.banner or t_ns < pending.boot_at_ns:
            return self._sample_line(t_ns)
        pending.banner = False
        if pending.restart:
            pending.restart = False
            self._seq = 0
            elapsed_ns = t_ns - self.start_ns
            if self._clock_factor != 1.0:
                self._device_time_start_us = -(round(elapsed_ns * self._clock_factor) // 1000)
            else:
                self._device_time_start_us = -(elapsed_ns // 1000)
        banner = b""
        if not (self._silences_ns and self._silenced(t_ns)):  # unplugged: lost with everything else
            banner = self.banner or firmware_banner(self.rate_hz)
            self.counts.banners += 1
        return banner + self._sample_line(t_ns)

    def _sample_line(self, t_ns: int) -> bytes:
        elapsed_ns = t_ns - self.start_ns
        rng = self._rng
        tension = self.tension_n(t_ns)
        if self.artefacts is not None:
            tension = self.artefacts.apparent_tension_n(tension, elapsed_ns / 1e9, 1.0 / self.rate_hz)
        counts = self.signal.counts(tension, elapsed_ns / 1e9, self._normal())
        seq = self._seq
        if self._clock_factor != 1.0:
            device_time_us = self._device_time_start_us + round(elapsed_ns * self._clock_factor) // 1000
        else:
            device_time_us = self._device_time_start_us + elapsed_ns // 1000
        self._k += 1
        self._seq += 1
        tally = self.counts
        tally.samples += 1
        if self._indicator is None and self.poll_command is None:
            reading = DeviceReading(counts, seq, device_time_us)
        else:
            reading = self._reading(counts, seq, device_time_us)
        if self._silences_ns and self._silenced(t_ns):
            tally.silenced_samples += 1
            return b""
        pending, faults = self._pending, self.faults
        if pending.gap_samples:
            pending.gap_samples -= 1
            self.counts.gap_samples += 1
            return b""
        if faults.gap_per_line and rng.random() < faults.gap_per_line:
            pending.gap_samples = rng.randint(1, faults.gap_samples_max) - 1
            self.counts.gap_samples += 1
            return b""
        line = self.codec.encode(reading)
        prefix = b""
        garbage = pending.garbage_bytes
        if faults.garbage_per_line and rng.random() < faults.garbage_per_line:
            garbage.append(rng.randint(1, faults.garbage_bytes_max))
        if garbage:
            n = sum(garbage)
            garbage.clear()
            prefix = bytes(rng.choices(_GARBAGE_ALPHABET, k=n))
            self.counts.garbage_bytes += n
        if pending.truncate or (faults.truncate_per_line and rng.random() < faults.truncate_per_line):
            pending.truncate = max(0, pending.truncate - 1)
            self.counts.truncated_lines += 1
            # Keep the header so the host can tell a truncated line from garbage; lose the terminator.
            return prefix + line[: rng.randint(self.codec.header_bytes, len(line) - 3)]
        if pending.bad_checksum or (
            faults.bad_checksum_per_line and rng.random() < faults.bad_checksum_per_line
        ):
            pending.bad_checksum = max(0, pending.bad_checksum - 1)
            self.counts.bad_checksums += 1
            star = line.rindex(b"*")
            wrong = int(line[star + 1 : star + 3], 16) ^ rng.randint(1, 255)
            return prefix + line[: star + 1] + b"%02X" % wrong + line[star + 3 :]
        self.counts.lines_sent += 1
        if reading.overload:
            self.counts.overload_lines += 1
        return prefix + line

    def _reading(self, counts: int, seq: int, device_time_us: int) -> DeviceReading:
        indicator = self._indicator
        if indicator is None:
            if isinstance(self.codec, ValueUnitCodec):  # a gauge: its reading in micronewtons
                signal = self.signal
                micronewtons = round(
                    (counts - signal.offset_counts) / signal.gain_counts_per_n * MICRONEWTONS_PER_N
                )
                overload = counts in (signal.adc_min, signal.adc_max)
                return DeviceReading(micronewtons, seq, device_time_us, overload=overload)
            return DeviceReading(counts, seq, device_time_us)
        display = round((counts - self.signal.offset_counts) * self._display_per_count)
        saturated = abs(display) > indicator.max_display_raw or counts in (
            self.signal.adc_min,
            self.signal.adc_max,
        )
        recent = self._recent_display
        recent.append(display)
        if len(recent) > 8:
            del recent[0]
        stable = max(recent) - min(recent) <= 2
        return DeviceReading(display, seq, device_time_us, stable=stable, overload=saturated)
