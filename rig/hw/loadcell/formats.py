r"""Load-cell line formats: a registry of codecs and the incremental line decoder the driver uses.

A codec turns one device reading into the bytes of one line (`encode`, used by the emulator) and
one received line back into a `DecodedLine` (`decode`, used by the driver). `LineDecoder` splits a
byte stream into lines, resynchronises after garbage and truncated lines, and counts what it had
to throw away. The formats are specified for firmware writers in `protocols/loadcell-formats.md`.

The plain decoder (`decode` of each codec, `LineDecoder.feed`) is the specification. The one fast
path, `LineDecoder.feed_columns` (what the driver calls), comes after it in this module, gives the
same lines and counters, and is tested against `feed` (tests/test_loadcell_formats.py).

* `rig-lc1`, the rig's own: `$LC,<seq>,<t_us>,<raw>*<hh>\r\n` with an NMEA-style XOR checksum, and
  information lines `#<text>\r\n` (a boot banner `#BOOT ...`, warnings), which the decoder counts and
  hands over (`take_info`) but never turns into samples or counts as damage.
* `indicator-st`, a commercial weighing-indicator style: `ST,GS,+0001.23kg\r\n` (no sequence
  number, no device clock, no checksum).
* `value-unit`, a polled force gauge's answer (Mark-10 style): `-18.78 lbF\r\n`, a value and a
  force unit (N, kN, gf, kgf, ozf, lbf), sent once per poll command (`?` CR). The codec converts the
  value to newtons: its `raw` is micronewtons.

What every layer needs of a format besides its codec (longest line, poll command) is its entry in
`rig.vocabulary.LOADCELL_FORMAT_TRAITS`.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import repeat
from typing import NamedTuple, Protocol, assert_never

import numpy as np

from rig.errors import InputError
from rig.vocabulary import LOADCELL_FORMAT_TRAITS, LoadCellFormatName

SEQ_MODULUS = 1 << 16  # rig-lc1 sequence counter wraps at 65536
DEVICE_TIME_MODULUS_US = 1 << 32  # rig-lc1 device clock wraps at 2**32 us (about 71.6 min)
RAW_MIN = -(1 << 31)
RAW_MAX = (1 << 31) - 1


class LineError(ValueError):
    """A received line that is not a valid line of the format (malformed or truncated)."""


class ChecksumError(LineError):
    """A well-formed line whose checksum does not match its contents."""


# rig-lc1 information lines: "#", then printable ASCII except "#" and "$" (so neither kind of line
# start hides inside one), then CR LF; at most 74 bytes in all, the decoder's limit for a line that
# is still arriving (2 x the longest data line). A banner starts "#BOOT": after a sample, a restart.
INFO_LINE_START = b"#"
BANNER_PREFIX = b"#BOOT"
MAX_INFO_LINE_BYTES = 74
_INFO_LINE = re.compile(rb"#[\x20-\x22\x25-\x7e]{0,%d}\r?" % (MAX_INFO_LINE_BYTES - 3))


@dataclass(frozen=True, slots=True)
class InfoLine:
    """An information line as received: what the device said, and where it came in the stream."""

    text: str  # without the "#" and the terminator
    line_bytes: int  # bytes it took on the wire, terminator included
    banner: bool  # a boot banner (`#BOOT ...`)
    restart: bool  # a banner after a sample since the decoder started: the device restarted
    sample_index: int  # samples the same `feed` call returned before it


class DeviceReading(NamedTuple):
    """What a device puts on one line (the emulator's input to `encode`)."""

    raw: int  # ADC counts, or the indicator's displayed value in units of its last digit
    seq: int = 0  # ignored by formats without a sequence counter
    device_time_us: int = 0  # ignored by formats without a device clock
    stable: bool = True
    overload: bool = False
    net: bool = False


class DecodedLine(NamedTuple):
    """One valid line as the host understood it."""

    raw: int
    seq: int | None
    device_time_us: int | None
    stable: bool = True
    overload: bool = False
    net: bool = False
    unit: str | None = None  # indicator unit, e.g. "kg"
    decimals: int = 0  # indicator digits after the decimal point: value = raw * 10**-decimals


# Valid lines as columns: raw, seq, device_time_us (one entry per line, in order).
Columns = tuple[list[int], Sequence[int | None], Sequence[int | None]]


class LineCodec(Protocol):
    """One line format: how a device writes a reading and how the host reads it back."""

    name: LoadCellFormatName
    has_sequence: bool  # lines carry a 16-bit wrapping sequence counter
    has_checksum: bool  # corruption is detectable per line
    max_line_bytes: int  # longest valid line, terminator included
    header_bytes: int  # a truncated line is recognisable as one if at least this many bytes survive
    has_info_lines: bool  # lines starting with `#` are information, not samples (INFO_LINE_START)

    def encode(self, reading: DeviceReading) -> bytes:
        """The bytes of one line, terminator included."""
        ...

    def decode(self, line: bytes) -> DecodedLine:
        r"""Decode one line without its `\n` (a trailing `\r` is allowed); raise `LineError`."""
        ...

    def last_line_start(self, segment: bytes) -> int:
        """Index of the last place a line could start in `segment`, or -1."""
        ...

    def count_line_starts(self, segment: bytes) -> int:
        """How many line starts `segment` contains (each one a truncated line when discarded)."""
        ...


def nmea_checksum(body: bytes) -> int:
    """XOR of every byte of `body` (the bytes between `$` and `*`)."""
    checksum = 0
    for byte in body:
        checksum ^= byte
    return checksum


_LC1_LINE = re.compile(rb"\$LC,([0-9]{1,5}),([0-9]{1,10}),(-?[0-9]{1,10})\*([0-9A-Fa-f]{2})\r?")


class RigLc1Codec:
    r"""`$LC,<seq>,<t_us>,<raw>*<hh>\r\n`: sequence, device microseconds, raw counts, XOR checksum."""

    name = LoadCellFormatName.RIG_LC1
    has_sequence = True
    has_checksum = True
    max_line_bytes = LOADCELL_FORMAT_TRAITS[LoadCellFormatName.RIG_LC1].max_line_bytes  # 37
    header_bytes = 1  # the `$`
    has_info_lines = True

    def encode(self, reading: DeviceReading) -> bytes:
        """Format one reading; seq and device time are reduced modulo their wrap."""
        if not RAW_MIN <= reading.raw <= RAW_MAX:
            raise ValueError(f"raw {reading.raw} outside the signed 32-bit range of rig-lc1")
        body = b"LC,%d,%d,%d" % (
            reading.seq % SEQ_MODULUS,
            reading.device_time_us % DEVICE_TIME_MODULUS_US,
            reading.raw,
        )
        return b"$%s*%02X\r\n" % (body, nmea_checksum(body))

    def decode(self, line: bytes) -> DecodedLine:
        """Parse and verify one line."""
        match = _LC1_LINE.fullmatch(line)
        if match is None:
            raise LineError("not a rig-lc1 line")
        seq_text, time_text, raw_text, checksum_text = match.groups()
        if nmea_checksum(line[1 : match.start(4) - 1]) != int(checksum_text, 16):
            raise ChecksumError("rig-lc1 checksum mismatch")
        seq = int(seq_text)
        device_time_us = int(time_text)
        raw = int(raw_text)
        if seq >= SEQ_MODULUS or device_time_us >= DEVICE_TIME_MODULUS_US or not RAW_MIN <= raw <= RAW_MAX:
            raise LineError("rig-lc1 field out of range")
        return DecodedLine(raw, seq, device_time_us)

    def last_line_start(self, segment: bytes) -> int:
        """The last `$`."""
        return segment.rfind(b"$")

    def count_line_starts(self, segment: bytes) -> int:
        """Number of `$` bytes."""
        return segment.count(b"$")


_INDICATOR_START = re.compile(rb"(?:ST|US|OL),(?:GS|NT),")
_INDICATOR_LINE = re.compile(rb"(ST|US|OL),(GS|NT),([+-])([0-9. ]{7})([A-Za-z]{1,3})\r?")
INDICATOR_UNITS = ("kg", "g", "lb", "N", "kN", "t")


class IndicatorStCodec:
    r"""`ST,GS,+0001.23kg\r\n`: stability, gross/net, sign, 7-character value, unit.

    Status ST = stable, US = unstable, OL = overload; GS = gross, NT = net. The value field is
    7 characters, the decimal point included, right-aligned with leading zeros (leading spaces
    are accepted). `raw` is the value in units of its last digit, so 0001.23 -> raw 123,
    decimals 2.
    """

    name = LoadCellFormatName.INDICATOR_ST
    has_sequence = False
    has_checksum = False
    max_line_bytes = LOADCELL_FORMAT_TRAITS[LoadCellFormatName.INDICATOR_ST].max_line_bytes  # 19
    header_bytes = len(b"ST,GS,")
    has_info_lines = False

    def __init__(self, decimals: int = 2, unit: str = "kg") -> None:
        if not 0 <= decimals <= 5:
            raise InputError(f"indicator-st: decimals {decimals}; allowed: 0-5")
        if unit not in INDICATOR_UNITS:
            raise InputError(f"indicator-st: unit {unit!r}; allowed: {', '.join(INDICATOR_UNITS)}")
        self.decimals = decimals
        self.unit = unit
        width = 7 - (decimals + 1 if decimals else 0)
        self.max_display_raw = 10 ** (width + decimals) - 1

    def encode(self, reading: DeviceReading) -> bytes:
        """Format one reading; values that do not fit in 7 characters are clamped and flagged OL."""
        magnitude = abs(reading.raw)
        overload = reading.overload or magnitude > self.max_display_raw
        magnitude = min(magnitude, self.max_display_raw)
        if self.decimals:
            scale = 10**self.decimals
            value = b"%d.%0*d" % (magnitude // scale, self.decimals, magnitude % scale)
        else:
            value = b"%d" % magnitude
        status = b"OL" if overload else (b"ST" if reading.stable else b"US")
        return b"%s,%s,%s%s%s\r\n" % (
            status,
            b"NT" if reading.net else b"GS",
            b"-" if reading.raw < 0 else b"+",
            value.rjust(7, b"0"),
            self.unit.encode("ascii"),
        )

    def decode(self, line: bytes) -> DecodedLine:
        """Parse one line (any decimals and unit)."""
        match = _INDICATOR_LINE.fullmatch(line)
        if match is None:
            raise LineError("not an indicator-st line")
        status, mode, sign, value, unit = match.groups()
        digits = value.strip(b" ")
        if not digits or b" " in digits or digits.count(b".") > 1 or digits in (b".",):
            raise LineError("indicator-st value field malformed")
        point = digits.find(b".")
        decimals = 0 if point < 0 else len(digits) - point - 1
        raw = int(digits.replace(b".", b""))
        return DecodedLine(
            -raw if sign == b"-" else raw,
            None,
            None,
            stable=status == b"ST",
            overload=status == b"OL",
            net=mode == b"NT",
            unit=unit.decode("ascii"),
            decimals=decimals,
        )

    def last_line_start(self, segment: bytes) -> int:
        """Start of the last `ST,GS,`-style header."""
        start = -1
        for match in _INDICATOR_START.finditer(segment):
            start = match.start()
        return start

    def count_line_starts(self, segment: bytes) -> int:
        """Number of status headers."""
        return len(_INDICATOR_START.findall(segment))


# Force units of a value-unit line, in newtons (exact by definition: NIST SP 811, appendix B).
# Keys are lower case; a device may write any case (Mark-10 writes `lbF`, `kgF`, `gF`, `ozF`).
FORCE_UNITS_N: dict[str, float] = {
    "n": 1.0,
    "kn": 1000.0,
    "gf": 0.00980665,
    "kgf": 9.80665,
    "ozf": 0.27801385095378125,  # lbf / 16
    "lbf": 4.4482216152605,  # 0.45359237 kg x 9.80665 m/s^2
}
# How a Mark-10 gauge writes each unit (the emulator's spelling; the decoder takes any case).
_GAUGE_UNIT_TEXT = {"n": "N", "kn": "kN", "gf": "gF", "kgf": "kgF", "ozf": "ozF", "lbf": "lbF"}
MICRONEWTONS_PER_N = 1_000_000
_VALUE_UNIT_LINE = re.compile(rb"([+-]?)([0-9]{1,9}(?:\.[0-9]{1,6})?|\.[0-9]{1,6}) ?([A-Za-z]{1,3})\r?")
_VALUE_UNIT_START = re.compile(rb"[+-]?[0-9.]")


class ValueUnitCodec:
    r"""`-18.78 lbF\r\n`: a signed decimal value, an optional space, a force unit; one line per poll.

    `raw` is the value in micronewtons (`decimals` 6, `unit` "N"), so the driver's calibration is
    nominally 1e-6 N per count whatever unit the gauge shows, and a unit changed on the gauge's
    keypad mid-run still reads right. `encode` writes `raw` (micronewtons) in this codec's `unit`
    with its `decimals`, as the emulated gauge displays it.
    """

    name = LoadCellFormatName.VALUE_UNIT
    has_sequence = False
    has_checksum = False
    max_line_bytes = LOADCELL_FORMAT_TRAITS[LoadCellFormatName.VALUE_UNIT].max_line_bytes
    header_bytes = 1  # a sign or a digit
    has_info_lines = False

    def __init__(self, unit: str = "lbf", decimals: int = 2) -> None:
        if unit.lower() not in FORCE_UNITS_N:
            raise InputError(f"value-unit: unit {unit!r}; allowed: {', '.join(_GAUGE_UNIT_TEXT.values())}")
        if not 0 <= decimals <= 3:
            raise InputError(f"value-unit: decimals {decimals}; allowed: 0-3")
        self.unit = unit.lower()
        self.decimals = decimals

    def encode(self, reading: DeviceReading) -> bytes:
        """The gauge's answer: `reading.raw` micronewtons shown in `unit` with `decimals`."""
        value = reading.raw / MICRONEWTONS_PER_N / FORCE_UNITS_N[self.unit]
        text = b"%.*f" % (self.decimals, value)
        if text.startswith(b"-") and float(text) == 0.0:
            text = text[1:]
        if len(text) > 10:
            raise ValueError(f"value {value:g} {self.unit} does not fit a value-unit line")
        return b"%s %s\r\n" % (text, _GAUGE_UNIT_TEXT[self.unit].encode("ascii"))

    def decode(self, line: bytes) -> DecodedLine:
        """Parse one line; the value in micronewtons."""
        match = _VALUE_UNIT_LINE.fullmatch(line)
        if match is None:
            raise LineError("not a value-unit line")
        sign, digits, unit = match.groups()
        unit_n = FORCE_UNITS_N.get(unit.decode("ascii").lower())
        if unit_n is None:
            raise LineError(f"value-unit: unknown unit {unit.decode('ascii')!r}")
        value = float(digits) * unit_n
        raw = round(value * MICRONEWTONS_PER_N)
        return DecodedLine(-raw if sign == b"-" else raw, None, None, unit="N", decimals=6)

    def last_line_start(self, segment: bytes) -> int:
        """Start of the last run of value characters that could begin a line."""
        start = -1
        for match in _VALUE_UNIT_START.finditer(segment):
            if match.start() == 0 or segment[match.start() - 1 : match.start()] not in b"0123456789.+-":
                start = match.start()
        return start

    def count_line_starts(self, segment: bytes) -> int:
        """Number of places a value could start (a sign or digit not inside another value)."""
        return sum(
            1
            for match in _VALUE_UNIT_START.finditer(segment)
            if match.start() == 0 or segment[match.start() - 1 : match.start()] not in b"0123456789.+-"
        )


def codec_class(name: LoadCellFormatName) -> Callable[[], LineCodec]:
    """The codec of one format (mypy names this match when a format is added)."""
    match name:
        case LoadCellFormatName.RIG_LC1:
            return RigLc1Codec
        case LoadCellFormatName.INDICATOR_ST:
            return IndicatorStCodec
        case LoadCellFormatName.VALUE_UNIT:
            return ValueUnitCodec
        case _:
            assert_never(name)


FORMATS: dict[LoadCellFormatName, Callable[[], LineCodec]] = {
    name: codec_class(name) for name in LoadCellFormatName
}


def get_codec(name: str) -> LineCodec:
    """A fresh codec for the format `name`; `InputError` listing the known formats otherwise."""
    try:
        factory = FORMATS[LoadCellFormatName(name)]
    except ValueError:
        raise InputError(
            f"load-cell format {name!r} unknown; allowed: {', '.join(sorted(FORMATS))}"
        ) from None
    return factory()


@dataclass(frozen=True, slots=True)
class DecoderCounts:
    """What a `LineDecoder` has seen so far."""

    bytes_received: int = 0
    lines_ok: int = 0
    corrupt_lines: int = 0  # malformed or truncated lines (recognisable by their header)
    checksum_failures: int = 0
    bytes_discarded: int = 0  # every received byte not part of a valid line
    sequence_gaps: int = 0  # places where the sequence counter skipped
    missing_samples: int = 0  # sequence numbers never received, summed over the gaps
    overload_lines: int = 0  # valid lines flagged as overload by the device
    info_lines: int = 0  # information lines (`#...`): neither samples nor damage
    restarts: int = 0  # boot banners after a sample: the device restarted (its seq restarts, no gap)


class LineDecoder:
    """Split a byte stream into lines and decode them, resynchronising after damage.

    Bytes are accounted for exactly: `bytes_received == bytes in valid lines (samples and
    information lines) + bytes_discarded + pending_bytes`. A discarded stretch that contains line
    headers counts one corrupt line per header (a truncated line glued to the next one); a stretch
    with no header is garbage and only adds to `bytes_discarded`. Sequence gaps are counted modulo
    2**16, so a silence longer than 65536 sample periods is under-counted (documented in
    protocols/loadcell-formats.md).

    Information lines (rig-lc1 `#...`) are collected for `take_info` and counted in `info_lines`;
    one may follow damage on the same line (a line cut short by a reset, then the banner). A boot
    banner after a sample is a restart: counted in `restarts`, and the sequence is followed afresh
    from the next sample instead of counting a gap.
    """

    def __init__(self, codec: LineCodec, max_line_bytes: int | None = None) -> None:
        self.codec = codec
        self._fast_lc1 = isinstance(codec, RigLc1Codec)  # `feed_columns` has a fast path for rig-lc1
        self._info_lines = codec.has_info_lines
        self.max_line_bytes = max_line_bytes or 2 * codec.max_line_bytes
        self._pending = b""
        self._last_seq: int | None = None
        self.bytes_received = 0
        self.lines_ok = 0
        self.corrupt_lines = 0
        self.checksum_failures = 0
        self.bytes_discarded = 0
        self.sequence_gaps = 0
        self.missing_samples = 0
        self.overload_lines = 0
        self.info_lines = 0
        self.restarts = 0
        self._new_info: list[InfoLine] = []

    @property
    def pending_bytes(self) -> int:
        """Bytes of an unfinished line held until its terminator arrives."""
        return len(self._pending)

    def counts(self) -> DecoderCounts:
        """A snapshot of the counters."""
        return DecoderCounts(
            self.bytes_received,
            self.lines_ok,
            self.corrupt_lines,
            self.checksum_failures,
            self.bytes_discarded,
            self.sequence_gaps,
            self.missing_samples,
            self.overload_lines,
            self.info_lines,
            self.restarts,
        )

    def take_info(self) -> list[InfoLine]:
        """The information lines received since the last call, in order."""
        info, self._new_info = self._new_info, []
        return info

    def feed(self, data: bytes) -> list[DecodedLine]:
        """Consume received bytes; return the valid lines completed by them, in order."""
        block = self._take_block(data)
        return self._decode_lines(block) if block else []

    def _take_block(self, data: bytes) -> bytes:
        r"""Count `data` in; return the complete lines now buffered (up to the last `\n`), keep the rest."""
        self.bytes_received += len(data)
        buffered = self._pending + data if self._pending else data
        end = buffered.rfind(b"\n") + 1
        tail = buffered[end:]
        if len(tail) > self.max_line_bytes:
            tail = self._drop_overlong(tail)
        self._pending = tail
        return buffered[:end]

    def _decode_lines(self, block: bytes) -> list[DecodedLine]:
        r"""Decode the lines of `block` (which ends with `\n`) one by one, resynchronising after damage."""
        segments = block.split(b"\n")
        segments.pop()  # the empty string after the final terminator
        lines: list[DecodedLine] = []
        followed = 0  # lines[:followed] have had their sequence accounted (before a restart)
        for segment in segments:
            try:
                lines.append(self.codec.decode(segment))
            except LineError:
                info = self._info_line(segment, len(lines)) if self._info_lines else None
                if info is None:
                    resynced = self._resync(segment)
                    if resynced is not None:
                        lines.append(resynced)
                elif info.restart and self.codec.has_sequence:
                    # The samples before the restart are followed as usual; after it, afresh.
                    self._account_sequence([line.seq for line in lines[followed:]])  # type: ignore[misc]
                    followed = len(lines)
                    self._last_seq = None
        if lines:
            self.lines_ok += len(lines)
            if self.codec.has_sequence:
                self._account_sequence([line.seq for line in lines[followed:]])  # type: ignore[misc]
            self.overload_lines += sum(1 for line in lines if line.overload)
        return lines

    def _info_line(self, segment: bytes, samples_before: int) -> InfoLine | None:
        """The information line ending `segment`, if there is one (damage before it is discarded)."""
        start = segment.rfind(INFO_LINE_START)
        if start < 0 or _INFO_LINE.fullmatch(segment, start) is None:
            return None
        if start > 0:
            prefix = segment[:start]
            self.bytes_discarded += len(prefix)
            self.corrupt_lines += self.codec.count_line_starts(prefix)
        line = segment[start:].rstrip(b"\r")
        banner = line.startswith(BANNER_PREFIX)
        restart = banner and self.lines_ok + samples_before > 0
        info = InfoLine(line[1:].decode("ascii"), len(segment) - start + 1, banner, restart, samples_before)
        self.info_lines += 1
        self.restarts += restart
        self._new_info.append(info)
        return info

    def _account_sequence(self, seqs: Sequence[int]) -> None:
        """Count the gaps in the sequence numbers of consecutive valid lines."""
        last = self._last_seq
        for seq in seqs:
            if last is not None and seq != (last + 1) % SEQ_MODULUS:
                self.sequence_gaps += 1
                self.missing_samples += (seq - last - 1) % SEQ_MODULUS
            last = seq
        self._last_seq = last

    def _resync(self, segment: bytes) -> DecodedLine | None:
        """Handle a segment that is not one valid line: find the last line start in it."""
        start = self.codec.last_line_start(segment)
        if start < 0:
            # Pure garbage (or an empty line): no header, so not counted as a corrupt line.
            self.bytes_discarded += len(segment) + 1
            return None
        if start > 0:
            prefix = segment[:start]
            self.bytes_discarded += len(prefix)
            self.corrupt_lines += self.codec.count_line_starts(prefix)
            segment = segment[start:]
        try:
            return self.codec.decode(segment)
        except ChecksumError:
            self.checksum_failures += 1
        except LineError:
            self.corrupt_lines += 1
        self.bytes_discarded += len(segment) + 1
        return None

    def _drop_overlong(self, tail: bytes) -> bytes:
        """An unterminated stretch longer than any line: keep only a plausible last line start."""
        start = self.codec.last_line_start(tail)
        keep = tail[start:] if start >= 0 and len(tail) - start <= self.codec.max_line_bytes else b""
        if not keep and self._info_lines:  # or an information line still arriving
            start = tail.rfind(INFO_LINE_START)
            if start >= 0 and len(tail) - start < MAX_INFO_LINE_BYTES and b"$" not in tail[start:]:
                keep = tail[start:]
        dropped = tail[: len(tail) - len(keep)]
        self.bytes_discarded += len(dropped)
        self.corrupt_lines += self.codec.count_line_starts(dropped)
        return keep

    # -- the fast path ----------------------------------------------------------------------------
    def feed_columns(self, data: bytes) -> Columns:
        """`feed` with the valid lines as columns (raw, seq, device_time_us): same lines, same counters.

        FAST PATH, for the driver (`SerialLoadCell`): `benchmarks/bench_loadcell.py` (parse and
        simulated chain) demanded it; before it the driver decoded 2.2-2.8x slower than a bare
        readline+split+int loop, after it about as fast (benchmarks/README.md). What it speeds up: a
        rig-lc1 block of complete lines that are all valid, the usual case, is matched by one C-level
        `findall` (no per-line `decode`, no `DecodedLine`), its checksums are computed together
        (`nmea_checksums`) and an unbroken sequence is checked in one comparison. Any other block
        (damage, a partial line, another format) goes line by line through `feed`'s code.
        """
        block = self._take_block(data)
        if not block:
            return [], [], []
        found = _LC1_TERMINATED_LINE.findall(block) if self._fast_lc1 else []
        valid = bool(found)
        if valid:
            bodies, seq_texts, time_texts, raw_texts, checksum_texts, crs = zip(*found, strict=True)
            # The matches tile the block exactly (so each one is a whole line, as `decode` sees it)
            # iff their lengths add up to the block's.
            valid = sum(map(len, bodies)) + sum(map(len, crs)) + _LC1_FIXED_BYTES * len(found) == len(block)
        if valid:
            checksums = nmea_checksums(bodies)
            # Compared as text (devices send upper case); lower-case hex is compared as numbers.
            valid = list(map(_UPPER_HEX.__getitem__, checksums)) == list(checksum_texts) or checksums == list(
                map(int, checksum_texts, repeat(16))
            )
        if valid:
            seqs = list(map(int, seq_texts))
            times = list(map(int, time_texts))
            raws = list(map(int, raw_texts))
            valid = (
                max(seqs) < SEQ_MODULUS
                and max(times) < DEVICE_TIME_MODULUS_US
                and min(raws) >= RAW_MIN
                and max(raws) <= RAW_MAX
            )
        if not valid:
            lines = self._decode_lines(block)
            return [ln.raw for ln in lines], [ln.seq for ln in lines], [ln.device_time_us for ln in lines]
        self.lines_ok += len(raws)
        last = self._last_seq
        first = seqs[0] if last is None else (last + 1) % SEQ_MODULUS
        if seqs == list(range(first, first + len(seqs))):  # never true across the wrap: seqs < 2**16
            self._last_seq = seqs[-1]  # unbroken: no gap to count
        else:
            self._account_sequence(seqs)
        return raws, seqs, times  # rig-lc1 has no overload flag to count


# -- for the fast paths: `LineDecoder.feed_columns` and the emulator's fault-free rig-lc1 lines ----

_NUMPY_CHECKSUM_MIN_LINES = 8  # below this, numpy's per-call overhead exceeds what it saves
_CHECKSUM_SLOT_BYTES = 32  # every rig-lc1 body fits: at most 31 bytes


def nmea_checksums(bodies: Sequence[bytes]) -> list[int]:
    """`nmea_checksum` of each body (each at most 32 bytes), in one numpy reduction for many bodies."""
    if len(bodies) < _NUMPY_CHECKSUM_MIN_LINES:
        return list(map(nmea_checksum, bodies))
    # One zero-padded 32-byte row per body (zeros do not change an XOR), reduced along the rows.
    padded = b"".join(map(bytes.ljust, bodies, repeat(_CHECKSUM_SLOT_BYTES), repeat(b"\0")))
    rows = np.frombuffer(padded, np.uint8).reshape(-1, _CHECKSUM_SLOT_BYTES)
    checksums: list[int] = np.bitwise_xor.reduce(rows, axis=1).tolist()
    return checksums


# A rig-lc1 line (`_LC1_LINE`) with its terminator; the checksummed body and the optional CR as groups too.
_LC1_TERMINATED_LINE = re.compile(
    rb"\$(LC,([0-9]{1,5}),([0-9]{1,10}),(-?[0-9]{1,10}))\*([0-9A-Fa-f]{2})(\r?)\n"
)
_LC1_FIXED_BYTES = len(b"$*hh\n")  # bytes of a terminated line outside its body and CR groups
_UPPER_HEX = [b"%02X" % byte for byte in range(256)]
