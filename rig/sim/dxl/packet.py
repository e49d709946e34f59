"""Dynamixel Protocol 2.0 on the wire, pure: CRC-16, byte stuffing, packet builders, a streaming framer.

No I/O and no clock: times are passed in as integer nanoseconds. Facts (docs/design.md §7):

* Packet: `FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM... | CRC_L CRC_H`; LEN counts the
  instruction byte, the (stuffed) params and the CRC. Status packets use INST = 0x55 followed by ERR.
* CRC-16: polynomial 0x8005, not reflected, initial value 0, no final XOR, over everything from the
  first header byte through the last param, as sent (i.e. after stuffing).
* Stuffing: in the instruction/params, every `FF FF FD` is followed by an extra `FD`.
* The Python SDK sends instructions **unstuffed** (it discards `addStuffing`'s result), so the framer
  takes the packet length from LEN and never rescans for a header inside a packet.
* Fast Sync/Bulk Read replies are one unstuffed packet from ID 0xFE in which every entry ends with a
  CRC over the whole packet so far; the last one is the packet CRC.
"""

from __future__ import annotations

import sys
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from rig.hw.dxl import error_codes as _errors

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 252
STATUS_INSTRUCTION = 0x55
MIN_LENGTH = 3  # INST + CRC
MAX_LENGTH = 1024 - 7  # the SDK's packet buffers are 1 KiB including the 7-byte header
STALE_PARTIAL_NS = 100_000_000  # a partial packet older than this is dropped and the framer resyncs

# Instructions.
PING = 0x01
READ = 0x02
WRITE = 0x03
REG_WRITE = 0x04
ACTION = 0x05
FACTORY_RESET = 0x06
REBOOT = 0x08
CLEAR = 0x10
CONTROL_TABLE_BACKUP = 0x20
SYNC_READ = 0x82
SYNC_WRITE = 0x83
FAST_SYNC_READ = 0x8A
BULK_READ = 0x92
BULK_WRITE = 0x93
FAST_BULK_READ = 0x9A

# ERR byte: bit 7 alert, bits 0-6 the error number; defined once, with the driver's decoding.
ERR_ALERT = _errors.ALERT_BIT
ERR_RESULT_FAIL = _errors.ERRNUM_RESULT_FAIL
ERR_INSTRUCTION = _errors.ERRNUM_INSTRUCTION
ERR_CRC = _errors.ERRNUM_CRC
ERR_DATA_RANGE = _errors.ERRNUM_DATA_RANGE
ERR_DATA_LENGTH = _errors.ERRNUM_DATA_LENGTH
ERR_DATA_LIMIT = _errors.ERRNUM_DATA_LIMIT
ERR_ACCESS = _errors.ERRNUM_ACCESS

CLEAR_MULTI_TURN_PARAMS = b"\x01\x44\x58\x4c\x22"


def _make_crc_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE = _make_crc_table()
_LITTLE_ENDIAN = sys.byteorder == "little"


def _make_crc_word_table() -> tuple[int, ...]:
    """CRC_TABLE extended to 16-bit words: entry `w` is the CRC (from 0) of the big-endian bytes of `w`.

    With a 16-bit CRC, two bytes `hi lo` move `crc` to `table[crc ^ (hi << 8 | lo)]`.
    """
    t = CRC_TABLE
    return tuple([((a << 8) & 0xFFFF) ^ t[(a >> 8) ^ lo] for a in t for lo in range(256)])


# Built at import (~10 ms), not on first use: a pty server must not add that to its first reply.
CRC_WORD_TABLE = _make_crc_word_table()


def crc16(data: bytes | bytearray | memoryview | Sequence[int], crc: int = 0) -> int:
    """CRC-16 (0x8005, MSB first, init `crc`), continuing from `crc` so it can be computed in pieces."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        data = bytes(data)
    odd = len(data) & 1
    words = array("H")
    words.frombytes(memoryview(data)[:-1] if odd else data)
    if _LITTLE_ENDIAN:
        words.byteswap()
    table = CRC_WORD_TABLE
    for w in words:
        crc = table[crc ^ w]
    if odd:  # the last byte on its own
        crc = ((crc << 8) ^ CRC_TABLE[(crc >> 8) ^ data[-1]]) & 0xFFFF
    return crc


def stuff(payload: bytes | bytearray) -> bytes:
    """Insert `FD` after every `FF FF FD` in `payload` (instruction byte through the last param).

    Only the payload is scanned, as the spec says; the header's own `FF FF FD` is not part of it.
    """
    if b"\xff\xff\xfd" not in payload:
        return bytes(payload)
    return bytes(payload).replace(b"\xff\xff\xfd", b"\xff\xff\xfd\xfd")


def unstuff(payload: bytes | bytearray) -> bytes:
    """Remove the `FD` that follows every `FF FF FD` in `payload`: the inverse of `stuff`."""
    if b"\xff\xff\xfd\xfd" not in payload:
        return bytes(payload)
    return bytes(payload).replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


def _packet(servo_id: int, payload: bytes) -> bytes:
    length = len(payload) + 2
    head = HEADER + bytes((servo_id, length & 0xFF, length >> 8))
    body = head + payload
    crc = crc16(body)
    return body + bytes((crc & 0xFF, crc >> 8))


def build_instruction(
    servo_id: int, instruction: int, params: bytes | Iterable[int] = b"", *, stuffed: bool = True
) -> bytes:
    """An instruction packet; `stuffed=False` reproduces what the Python SDK actually sends."""
    payload = bytes((instruction,)) + bytes(params)
    return _packet(servo_id, stuff(payload) if stuffed else payload)


def build_status(servo_id: int, error: int, params: bytes | Iterable[int] = b"") -> bytes:
    """A status packet, stuffed per the spec (real servos stuff their replies)."""
    return _packet(servo_id, stuff(bytes((STATUS_INSTRUCTION, error)) + bytes(params)))


def build_fast_status(
    entries: Sequence[tuple[int, int, bytes]], announced_length: int | None = None
) -> bytes:
    """A Fast Sync/Bulk Read reply from `(error, id, data)` entries, unstuffed, with cumulative CRCs.

    LEN = 1 + sum(len(data) + 4). `announced_length` overrides it, to reproduce a reply in which a
    device did not answer: the first device announces every requested entry, fewer bytes follow.
    """
    if not entries:
        raise ValueError("a fast-read reply needs at least one entry")
    length = 1 + sum(len(d) + 4 for _, _, d in entries) if announced_length is None else announced_length
    head = HEADER + bytes((BROADCAST_ID, length & 0xFF, length >> 8, STATUS_INSTRUCTION))
    out = bytearray(head)
    crc = _fast_head_crc.get(length)
    if crc is None:
        crc = _fast_head_crc[length] = crc16(head)
    tail = b""  # the previous entry's CRC bytes: the next CRC runs over them too
    for error, servo_id, data in entries:
        chunk = bytes((error, servo_id)) + bytes(data)
        out += chunk
        crc = crc16(tail + chunk, crc)
        tail = bytes((crc & 0xFF, crc >> 8))
        out += tail
    return bytes(out)


_fast_head_crc: dict[int, int] = {}  # CRC of a fast-read reply's 8 header bytes, by LEN


@dataclass(frozen=True, slots=True)
class Frame:
    """One framed packet as received: the raw bytes and whether its CRC matched."""

    raw: bytes
    end_ns: int  # time at which its last byte was fed
    crc_ok: bool

    @property
    def servo_id(self) -> int:
        """The ID byte."""
        return self.raw[4]

    @property
    def instruction(self) -> int:
        """The instruction byte (0x55 for status packets)."""
        return self.raw[7]

    @property
    def payload(self) -> bytes:
        """Instruction through last param, unstuffed."""
        return unstuff(self.raw[7:-2])

    @property
    def params(self) -> bytes:
        """Params of an instruction packet, unstuffed."""
        return self.payload[1:]


class Framer:
    """Streaming framer: feed bytes as they arrive, get complete packets out, resync after garbage.

    A packet starts at `FF FF FD 00`; its length comes from LEN (never from rescanning). A LEN that
    cannot be valid makes the framer skip one byte and look for the next header. A partial packet
    whose last byte is older than `stale_ns` when more bytes arrive is discarded.
    """

    def __init__(self, stale_ns: int = STALE_PARTIAL_NS) -> None:
        self._buf = bytearray()
        self._last_ns = 0
        self._stale_ns = stale_ns
        self._last_good = b""  # the last packet whose CRC checked
        self.discarded_bytes = 0  # garbage and stale partials, for diagnostics

    @property
    def pending(self) -> int:
        """Bytes held for an incomplete packet."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop any partial packet."""
        self.discarded_bytes += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray, now_ns: int) -> list[Frame]:
        """Append `data` received at `now_ns`; return every packet completed by it."""
        buf = self._buf
        if buf and now_ns - self._last_ns > self._stale_ns:
            self.reset()
        self._last_ns = now_ns
        buf += data
        frames: list[Frame] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # Keep a possible header prefix (up to 3 bytes) for the next feed.
                keep = 0
                for k in (3, 2, 1):
                    if len(buf) >= k and buf[-k:] == HEADER[:k]:
                        keep = k
                        break
                self.discarded_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return frames
            if start:
                self.discarded_bytes += start
                del buf[:start]
            if len(buf) < 7:
                return frames
            length = buf[5] | (buf[6] << 8)
            if length < MIN_LENGTH or length > MAX_LENGTH:
                self.discarded_bytes += 1
                del buf[:1]
                continue
            total = 7 + length
            if len(buf) < total:
                return frames
            raw = bytes(buf[:total])
            del buf[:total]
            if raw != self._last_good:  # a host repeats the same request (a state read) all the time
                if crc16(memoryview(raw)[:-2]) != (raw[-2] | (raw[-1] << 8)):
                    frames.append(Frame(raw, now_ns, False))
                    continue
                self._last_good = raw
            frames.append(Frame(raw, now_ns, True))


@dataclass(frozen=True, slots=True)
class Status:
    """A decoded (unstuffed) status packet."""

    servo_id: int
    error: int
    params: bytes


def parse_status(raw: bytes) -> Status:
    """Decode one complete status packet (ValueError on a bad header, length, CRC or instruction)."""
    if raw[:4] != HEADER or len(raw) < 11:
        raise ValueError("not a status packet: bad header or too short")
    length = raw[5] | (raw[6] << 8)
    if len(raw) != 7 + length:
        raise ValueError(f"status length field {length} does not match {len(raw)} bytes")
    if crc16(raw[:-2]) != (raw[-2] | (raw[-1] << 8)):
        raise ValueError("status CRC mismatch")
    payload = unstuff(raw[7:-2])
    if payload[0] != STATUS_INSTRUCTION:
        raise ValueError(f"instruction byte {payload[0]:#04x} is not a status (0x55)")
    return Status(raw[4], payload[1], payload[2:])


def parse_fast_status(raw: bytes) -> list[tuple[int, int, bytes]]:
    """Split a fast-read reply into `(error, id, data)` entries given equal-length data, checking every CRC.

    The stride is not in the packet; it is recovered from the cumulative CRCs, so entries may differ
    in length (fast bulk read). ValueError when no consistent split exists.
    """
    if raw[:4] != HEADER or raw[4] != BROADCAST_ID or raw[7] != STATUS_INSTRUCTION:
        raise ValueError("not a fast-read reply")
    length = raw[5] | (raw[6] << 8)
    if len(raw) != 7 + length:
        raise ValueError(f"fast-read length field {length} does not match {len(raw)} bytes")
    entries: list[tuple[int, int, bytes]] = []
    pos = 8
    while pos < len(raw):
        # An entry is ERR ID DATA CRC: find the shortest DATA whose trailing CRC checks.
        for end in range(pos + 2, len(raw) - 1):
            crc = crc16(raw[:end])
            if crc == (raw[end] | (raw[end + 1] << 8)):
                entries.append((raw[pos], raw[pos + 1], bytes(raw[pos + 2 : end])))
                pos = end + 2
                break
        else:
            raise ValueError(f"no valid entry CRC after offset {pos}")
    return entries


def u16(lo_hi: bytes | bytearray, offset: int = 0) -> int:
    """Little-endian 16-bit value at `offset`."""
    return lo_hi[offset] | (lo_hi[offset + 1] << 8)
