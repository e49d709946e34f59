"""Emulated servos that answer Dynamixel Protocol 1.0, as an X-series servo switched to it does.

An X-series servo whose Protocol Type (13) is 1 speaks Protocol 1.0 over the same control table
(only addresses below 256 reachable) and ignores Protocol 2.0 packets: a Protocol 2.0 host does not
find it. `Protocol1Bus` frames 1.0 packets for the same `Servo` objects the 2.0 bus serves and has
the same `feed`/`baud` interface, so `rig sim servos --protocol 1.0` serves it on a pty.

Packets (ROBOTIS e-manual, Protocol 1.0): instruction `FF FF ID LEN INST PARAM... CHK`, status
`FF FF ID LEN ERR PARAM... CHK`, LEN = params + 2, CHK = ~(ID + LEN + INST/ERR + params) & 0xFF.
Ping, Read and Write are answered (a broadcast gets no status); any other instruction gets the
Instruction error bit (64). The 2.0 error numbers map onto the 1.0 error bits: range, limit,
length and access errors become the Range bit (8) *(assumption: the manual does not say)*.
"""

from __future__ import annotations

from collections.abc import Iterable

from rig.sim.dxl.emulated_bus import BITS_PER_BYTE, Reply
from rig.sim.dxl.servo import Result, Servo

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
PING, READ, WRITE = 0x01, 0x02, 0x03
ERROR_RANGE = 0x08
ERROR_CHECKSUM = 0x10
ERROR_INSTRUCTION = 0x40
PROTOCOL_TYPE_ADDRESS = 13
MAX_ADDRESS = 255  # addresses above are out of reach under Protocol 1.0


def checksum(body: bytes) -> int:
    """The 1.0 checksum of ID, LEN, INST/ERR and params."""
    return ~sum(body) & 0xFF


def build_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """A 1.0 status packet."""
    body = bytes((servo_id, len(params) + 2, error)) + params
    return HEADER + body + bytes((checksum(body),))


def build_instruction(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A 1.0 instruction packet (for tests)."""
    body = bytes((servo_id, len(params) + 2, instruction)) + params
    return HEADER + body + bytes((checksum(body),))


def _error_bits(result: Result) -> int:
    return ERROR_RANGE if result.error else 0


class Protocol1Bus:
    """Servos on one line answering Protocol 1.0 (see the module docstring)."""

    def __init__(self, servos: Iterable[Servo], *, baud: int = 1_000_000) -> None:
        self.servos = list(servos)
        self.baud = baud
        self._buf = bytearray()
        self._line_free_ns = 0
        for servo in self.servos:
            servo.write(PROTOCOL_TYPE_ADDRESS, b"\x01", 0)  # what a switched servo reads back

    def feed(self, data: bytes, now_ns: int) -> list[Reply]:
        """Bytes the host starts writing at `now_ns`; the status packets, in the order they arrive."""
        byte_ns = BITS_PER_BYTE * 1_000_000_000 // self.baud
        end_ns = now_ns + len(data) * byte_ns
        self._buf += data
        replies: list[Reply] = []
        for servo_id, instruction, params in self._packets():
            for servo in self.servos:
                if servo.servo_id != servo_id or not servo.hears(end_ns, self.baud):
                    continue
                servo.note_traffic(end_ns)
                error, out = self._execute(servo, instruction, params, end_ns)
                if servo_id == BROADCAST_ID:
                    continue
                status = build_status(servo_id, error, out)
                start = max(end_ns, self._line_free_ns) + servo.register("Return Delay Time") * 2000
                finish = start + len(status) * byte_ns
                self._line_free_ns = finish
                replies.append(Reply(finish, status, servo_id))
        return replies

    def _packets(self) -> list[tuple[int, int, bytes]]:
        """Complete, checked packets from the buffer; garbage and other protocols are skipped."""
        buf = self._buf
        packets: list[tuple[int, int, bytes]] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                del buf[: max(0, len(buf) - 1)]
                return packets
            del buf[:start]
            if len(buf) < 4:
                return packets
            servo_id, length = buf[2], buf[3]
            if servo_id == 0xFF or length < 2:  # not 1.0 (a 2.0 header reads FF FF FD 00)
                del buf[:1]
                continue
            if len(buf) < 4 + length:
                return packets
            body = bytes(buf[2 : 3 + length])
            valid = checksum(body) == buf[3 + length]
            del buf[: 4 + length]
            if valid:
                packets.append((servo_id, body[2], body[3:]))

    def _execute(self, servo: Servo, instruction: int, params: bytes, now_ns: int) -> tuple[int, bytes]:
        if instruction == PING:
            return 0, b""
        if instruction == READ and len(params) == 2:
            address, length = params
            if address + length > MAX_ADDRESS + 1:
                return ERROR_RANGE, b""
            result = servo.read(address, length, now_ns)
            return _error_bits(result), result.params
        if instruction == WRITE and len(params) >= 2:
            result = servo.write(params[0], params[1:], now_ns)
            return _error_bits(result), b""
        return ERROR_INSTRUCTION, b""


__all__ = ["Protocol1Bus", "build_instruction", "build_status", "checksum"]
