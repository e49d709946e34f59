"""Fault injection on an emulated Dynamixel bus: lose, corrupt or delay replies; parse `--fault` specs.

Faults that belong to a servo (silence it, latch hardware-error bits, move it to another baud
rate) are methods on `Servo`/`EmulatedBus`; this module holds the reply-level faults, which sit
between the servos and the wire, and the text form used by `rig sim servos --fault`.

Spec grammar (one per `--fault`):
  drop:N[:ID]        drop the next N replies (of servo ID, if given)
  corrupt:N[:ID]     flip a bit in the CRC of the next N replies
  delay:N:MS[:ID]    send the next N replies MS milliseconds late
  silent:ID          servo ID ignores all traffic
  hwerror:ID:BITS    latch Hardware Error Status bits (e.g. 0x20 overload) on servo ID
  baud:ID:RATE       servo ID listens at RATE bit/s (so it ignores traffic at the bus rate)
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import assert_never

from rig.errors import InputError
from rig.hw.dxl.control_table import BAUD_REGISTER_BY_RATE
from rig.sim.kinds import ReplyFaultKind, ServoFaultFlag


@dataclass(slots=True)
class _ReplyFault:
    kind: ReplyFaultKind
    remaining: int
    servo_id: int | None
    delay_ns: int = 0


@dataclass(slots=True)
class _RateFault:
    kind: ReplyFaultKind
    probability: float
    servo_id: int | None
    delay_ns: int = 0


@dataclass
class ReplyFaults:
    """Reply faults: queued ones (consumed in the order added), random ones at a rate, muted servos.

    A muted servo still hears and obeys every instruction; only its replies are lost (a broken
    return line, or a transceiver that no longer drives the bus).
    """

    _queue: list[_ReplyFault] = field(default_factory=list)
    _rates: list[_RateFault] = field(default_factory=list)
    muted: set[int] = field(default_factory=set)
    rng: random.Random = field(default_factory=lambda: random.Random(0))
    dropped: int = 0
    corrupted: int = 0
    delayed: int = 0

    def at_rate(
        self, kind: ReplyFaultKind, probability: float, servo_id: int | None = None, delay_s: float = 0.05
    ) -> None:
        """Drop, corrupt or delay each reply (of `servo_id` only, when given) with `probability`."""
        if kind not in tuple(ReplyFaultKind) or not 0.0 <= probability <= 1.0:
            raise ValueError(f"reply fault {kind!r} at rate {probability}; allowed: drop/corrupt/delay, 0-1")
        self._rates.append(_RateFault(kind, probability, servo_id, round(delay_s * 1e9)))

    def mute(self, servo_id: int, muted: bool = True) -> None:
        """Lose every reply of `servo_id` (it still obeys), or stop doing so."""
        if muted:
            self.muted.add(servo_id)
        else:
            self.muted.discard(servo_id)

    def drop_next(self, n: int = 1, servo_id: int | None = None) -> None:
        """Drop the next `n` replies (of `servo_id` only, when given)."""
        self._add(_ReplyFault(ReplyFaultKind.DROP, n, servo_id))

    def corrupt_next(self, n: int = 1, servo_id: int | None = None) -> None:
        """Corrupt (flip one CRC bit of) the next `n` replies."""
        self._add(_ReplyFault(ReplyFaultKind.CORRUPT, n, servo_id))

    def delay_next(self, n: int = 1, delay_s: float = 0.05, servo_id: int | None = None) -> None:
        """Send the next `n` replies `delay_s` late."""
        self._add(_ReplyFault(ReplyFaultKind.DELAY, n, servo_id, round(delay_s * 1e9)))

    def clear(self) -> None:
        """Forget every queued fault."""
        self._queue.clear()

    @property
    def active(self) -> bool:
        """Whether any fault is queued, at a rate, or a servo is muted."""
        return bool(self._queue or self._rates or self.muted)

    def _add(self, fault: _ReplyFault) -> None:
        if fault.remaining < 1:
            raise ValueError(f"a {fault.kind} fault needs a count >= 1, got {fault.remaining}")
        self._queue.append(fault)

    def apply(self, servo_id: int, data: bytes) -> tuple[bytes | None, int]:
        """Pass one reply through the first matching fault: (bytes or None if dropped, extra delay ns)."""
        if servo_id in self.muted:
            self.dropped += 1
            return None, 0
        for rate in self._rates:
            if (rate.servo_id is None or rate.servo_id == servo_id) and self.rng.random() < rate.probability:
                return self._fault(rate.kind, data, rate.delay_ns)
        for fault in self._queue:
            if fault.servo_id is None or fault.servo_id == servo_id:
                fault.remaining -= 1
                if fault.remaining == 0:
                    self._queue.remove(fault)
                return self._fault(fault.kind, data, fault.delay_ns)
        return data, 0

    def _fault(self, kind: ReplyFaultKind, data: bytes, delay_ns: int) -> tuple[bytes | None, int]:
        match kind:
            case ReplyFaultKind.DROP:
                self.dropped += 1
                return None, 0
            case ReplyFaultKind.CORRUPT:
                self.corrupted += 1
                return data[:-1] + bytes((data[-1] ^ 0x01,)), 0
            case ReplyFaultKind.DELAY:
                self.delayed += 1
                return data, delay_ns
            case _:
                assert_never(kind)


@dataclass(frozen=True, slots=True)
class FaultSpec:
    """One parsed `--fault` flag."""

    kind: ServoFaultFlag
    count: int = 1
    servo_id: int | None = None
    delay_ms: float = 0.0
    bits: int = 0
    baud: int = 0


def _int(text: str, what: str, spec: str, lo: int, hi: int) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise InputError(f"--fault {spec}: {what} {text!r} is not an integer; allowed: {lo}..{hi}") from None
    if not lo <= value <= hi:
        raise InputError(f"--fault {spec}: {what} {value} out of range; allowed: {lo}..{hi}")
    return value


def parse_fault(spec: str) -> FaultSpec:
    """Parse one `--fault` spec (grammar in the module docstring); InputError naming the problem."""
    parts = spec.split(":")
    kind = ServoFaultFlag(parts[0]) if parts[0] in tuple(ServoFaultFlag) else None
    n = len(parts)
    if kind in (ServoFaultFlag.DROP, ServoFaultFlag.CORRUPT) and n in (2, 3):
        return FaultSpec(
            kind,
            count=_int(parts[1], "count", spec, 1, 1_000_000),
            servo_id=_int(parts[2], "id", spec, 0, 252) if n == 3 else None,
        )
    if kind is ServoFaultFlag.DELAY and n in (3, 4):
        ms = _int(parts[2], "delay ms", spec, 0, 60_000)
        return FaultSpec(
            kind,
            count=_int(parts[1], "count", spec, 1, 1_000_000),
            delay_ms=float(ms),
            servo_id=_int(parts[3], "id", spec, 0, 252) if n == 4 else None,
        )
    if kind is ServoFaultFlag.SILENT and n == 2:
        return FaultSpec(kind, servo_id=_int(parts[1], "id", spec, 0, 252))
    if kind is ServoFaultFlag.HWERROR and n == 3:
        return FaultSpec(
            kind, servo_id=_int(parts[1], "id", spec, 0, 252), bits=_int(parts[2], "bits", spec, 1, 255)
        )
    if kind is ServoFaultFlag.BAUD and n == 3:
        rate = _int(parts[2], "rate", spec, 0, 10_000_000)
        if rate not in BAUD_REGISTER_BY_RATE:
            allowed = ", ".join(str(r) for r in BAUD_REGISTER_BY_RATE)
            raise InputError(f"--fault {spec}: rate {rate} is not a Dynamixel baud rate; allowed: {allowed}")
        return FaultSpec(kind, servo_id=_int(parts[1], "id", spec, 0, 252), baud=rate)
    raise InputError(
        f"--fault {spec}: not a fault spec; allowed: drop:N[:ID], corrupt:N[:ID], delay:N:MS[:ID], "
        "silent:ID, hwerror:ID:BITS, baud:ID:RATE"
    )
