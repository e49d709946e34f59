"""An emulated half-duplex Dynamixel bus: frames host bytes, dispatches instructions, schedules replies.

Pure apart from the optional clock it keeps for convenience: `feed(data, now_ns)` takes the bytes
the host wrote at `now_ns` and returns the `Reply`s the servos send, each with the bus time at
which its last byte reaches the host (request transfer time at the line rate with 10 bits per
byte, then per servo its Return Delay Time and its own transfer time; replies never overlap).

Who answers (docs/design.md §7): unicast instructions are answered by the addressed servo subject
to its Status Return Level; broadcast Ping is answered by every servo in ID order; Sync/Bulk Read
by one status per listed servo in the order of the instruction; Fast Sync/Bulk Read by one
combined, unstuffed packet; every other broadcast runs silently (a broadcast Factory Reset with
option 0xFF is ignored). Servos whose baud rate differs from the line's hear nothing.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from rig.hw.dxl.control_table import ControlTable, table_for_model
from rig.sim.dxl import packet as p
from rig.sim.dxl.faults import ReplyFaults
from rig.sim.dxl.servo import Result, Servo

if TYPE_CHECKING:  # seams pulls in numpy; the pty server process does not need it
    from rig.hw.seams import Clock

BITS_PER_BYTE = 10
_READ_INSTRUCTIONS = (p.SYNC_READ, p.BULK_READ, p.FAST_SYNC_READ, p.FAST_BULK_READ)
_BROADCAST_ONLY = (p.SYNC_READ, p.SYNC_WRITE, p.BULK_READ, p.BULK_WRITE, p.FAST_SYNC_READ, p.FAST_BULK_READ)


@dataclass(frozen=True, slots=True)
class Reply:
    """Bytes a servo sends, due at the host at `due_ns` (`extra_delay_ns` of it from an injected fault)."""

    due_ns: int
    data: bytes
    servo_id: int
    extra_delay_ns: int = 0


@dataclass(slots=True)
class _Pending:
    servo: Servo
    data: bytes
    servo_id: int


class EmulatedBus:
    """Servos on one line, with reply-level fault injection (`faults`)."""

    def __init__(
        self, servos: Iterable[Servo] = (), *, baud: int = 1_000_000, clock: Clock | None = None
    ) -> None:
        self.clock = clock
        self.baud = baud  # the host's line rate; servos at another rate hear nothing
        self.faults = ReplyFaults()
        self.servos: list[Servo] = []
        self._by_id: dict[int, list[Servo]] = {}
        self._framer = p.Framer()
        self._line_free_ns = 0  # end of the last scheduled reply (the line is half duplex)
        self._now_ns = 0
        self.frames_received = 0
        self.crc_errors = 0
        for servo in servos:
            self.add_servo(servo)

    @classmethod
    def with_servos(
        cls,
        clock: Clock | None = None,
        ids: Sequence[int] = (1,),
        model: str | int | ControlTable | Sequence[str | int | ControlTable] = "XM430-W350",
        baud: int = 1_000_000,
        *,
        follow_clock: bool = False,
        **servo_kwargs: object,
    ) -> EmulatedBus:
        """A bus at `baud` with one servo per ID, all listening at `baud`.

        `model` is every servo's model, or a sequence of them, one per ID in order (a bus of mixed
        models, e.g. two XM430-W350 and an XM430-W210).

        Motion is integrated lazily whenever the bus is used, holding `external_torque_nm` constant
        since the last use. A world that changes the torque registers `clock.on_advance(bus.advance_to)`
        (or passes `follow_clock=True`, which does exactly that on a clock that has `on_advance`).
        `servo_kwargs` go to every `Servo` (firmware, motor, overload_time_s, boot_time_s, ...).
        """
        models = [model] * len(ids) if isinstance(model, str | int | ControlTable) else list(model)
        if len(models) != len(ids):
            raise ValueError(f"{len(models)} models for {len(ids)} servo ids {list(ids)}")
        tables = [m if isinstance(m, ControlTable) else table_for_model(m) for m in models]
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate servo ids in {list(ids)}")
        now = clock.monotonic_ns() if clock is not None else 0
        servos = [
            Servo(table, i, baud=baud, now_ns=now, **servo_kwargs)  # type: ignore[arg-type]
            for table, i in zip(tables, ids, strict=True)
        ]
        bus = cls(servos, baud=baud, clock=clock)
        if follow_clock and clock is not None and hasattr(clock, "on_advance"):
            clock.on_advance(bus.advance_to)
        return bus

    # ----- membership -------------------------------------------------------------------------------
    def add_servo(self, servo: Servo) -> None:
        """Connect a servo to the line."""
        self.servos.append(servo)
        servo.on_id_change.append(self._reindex)
        self._reindex(servo, None)

    def _reindex(self, servo: Servo, old_id: int | None) -> None:
        index: dict[int, list[Servo]] = {}
        for s in self.servos:
            index.setdefault(s.servo_id, []).append(s)
        self._by_id = index

    def servo(self, servo_id: int) -> Servo:
        """The servo with `servo_id` (KeyError if none)."""
        found = self._by_id.get(servo_id)
        if not found:
            raise KeyError(f"no servo with id {servo_id} on the bus (ids: {sorted(self._by_id)})")
        return found[0]

    def __getitem__(self, servo_id: int) -> Servo:
        """Same as `servo(servo_id)`."""
        return self.servo(servo_id)

    @property
    def ids(self) -> list[int]:
        """IDs present, sorted."""
        return sorted(self._by_id)

    # ----- faults (servo-level; reply-level ones are on `self.faults`) ----------------------------------
    def set_silent(self, servo_id: int, silent: bool = True) -> None:
        """Make a servo ignore all traffic (as if unplugged)."""
        self.servo(servo_id).silent = silent

    def set_hardware_error(self, servo_id: int, bits: int) -> None:
        """Latch Hardware Error Status bits on a servo."""
        self.servo(servo_id).set_hardware_error(bits, self._now_ns)

    # ----- time --------------------------------------------------------------------------------------
    def now_ns(self) -> int:
        """The clock's time if the bus has one, else the latest time it was given."""
        return self.clock.monotonic_ns() if self.clock is not None else self._now_ns

    def advance_to(self, now_ns: int) -> None:
        """Integrate every servo's motion up to `now_ns`; cheap and idempotent (an on_advance listener)."""
        if now_ns <= self._now_ns:
            return
        self._now_ns = now_ns
        for servo in self.servos:
            servo.advance_to(now_ns)

    def byte_time_ns(self) -> int:
        """Transfer time of one byte at the line rate (10 bits per byte)."""
        return BITS_PER_BYTE * 1_000_000_000 // self.baud

    # ----- traffic -----------------------------------------------------------------------------------
    def feed(self, data: bytes, now_ns: int) -> list[Reply]:
        """Bytes the host starts writing at `now_ns`; returns the replies, in the order they arrive."""
        byte_ns = self.byte_time_ns()
        end_ns = now_ns + len(data) * byte_ns
        self.advance_to(now_ns)
        frames = self._framer.feed(data, end_ns)
        replies: list[Reply] = []
        for frame in frames:
            self.frames_received += 1
            self.advance_to(end_ns)
            pending = self._dispatch(frame, end_ns)
            if not pending:
                continue
            start = max(end_ns, self._line_free_ns)
            for item in pending:
                delay_ns = item.servo._mem[9] * 2000  # Return Delay Time, 2 us units
                start += delay_ns
                finish = start + len(item.data) * byte_ns
                out, extra = (
                    self.faults.apply(item.servo_id, item.data) if self.faults.active else (item.data, 0)
                )
                if out is not None:
                    replies.append(Reply(finish + extra, out, item.servo_id, extra))
                start = finish
            self._line_free_ns = start
        replies.sort(key=lambda r: r.due_ns)
        return replies

    def _listening(self, servo_id: int, now_ns: int) -> list[Servo]:
        return [s for s in self._by_id.get(servo_id, ()) if s.hears(now_ns, self.baud)]

    def _status(self, servo: Servo, result: Result, servo_id: int | None = None) -> _Pending:
        sid = servo.servo_id if servo_id is None else servo_id
        return _Pending(servo, p.build_status(sid, servo.status_error(result.error), result.params), sid)

    def _dispatch(self, frame: p.Frame, now_ns: int) -> list[_Pending]:
        target = frame.servo_id
        if not frame.crc_ok:
            self.crc_errors += 1
            if target == p.BROADCAST_ID:
                return []
            return [
                self._status(s, Result(p.ERR_CRC))
                for s in self._listening(target, now_ns)
                if s.replies_to(frame.instruction)
            ]
        instruction = frame.instruction
        params = frame.params
        if target == p.BROADCAST_ID:
            return self._broadcast(instruction, params, now_ns)
        if target > p.MAX_ID:
            return []
        out = []
        for servo in self._listening(target, now_ns):
            # An ID change is answered with the old ID, and a Status Return Level change under the old level.
            reply_id, answers = servo.servo_id, servo.replies_to(instruction)
            if instruction in _BROADCAST_ONLY:
                servo.note_traffic(now_ns)
                result: Result | None = Result(p.ERR_INSTRUCTION)
            else:
                result = servo.execute(instruction, params, now_ns)
            if result is not None and answers:
                out.append(self._status(servo, result, reply_id))
        return out

    def _broadcast(self, instruction: int, params: bytes, now_ns: int) -> list[_Pending]:
        if instruction == p.PING:
            hearing = sorted((s for s in self.servos if s.hears(now_ns, self.baud)), key=lambda s: s.servo_id)
            return [self._status(s, s.execute(p.PING, params, now_ns) or Result()) for s in hearing]
        if instruction in (p.SYNC_READ, p.FAST_SYNC_READ):
            if len(params) < 5:
                return []
            address, length = p.u16(params, 0), p.u16(params, 2)
            return self._group_read(instruction, [(i, address, length) for i in params[4:]], now_ns)
        if instruction in (p.BULK_READ, p.FAST_BULK_READ):
            if len(params) < 5 or len(params) % 5:
                return []
            entries = [
                (params[k], p.u16(params, k + 1), p.u16(params, k + 3)) for k in range(0, len(params), 5)
            ]
            return self._group_read(instruction, entries, now_ns)
        if instruction == p.SYNC_WRITE:
            if len(params) < 4:
                return []
            address, length = p.u16(params, 0), p.u16(params, 2)
            body = params[4:]
            if length < 1 or len(body) % (length + 1):
                return []
            for k in range(0, len(body), length + 1):
                for servo in self._listening(body[k], now_ns):
                    servo.note_traffic(now_ns)
                    servo.write(address, body[k + 1 : k + 1 + length], now_ns)
            return []
        if instruction == p.BULK_WRITE:
            k = 0
            while k + 5 <= len(params):
                servo_id, address, length = params[k], p.u16(params, k + 1), p.u16(params, k + 3)
                data = params[k + 5 : k + 5 + length]
                if len(data) != length:
                    break
                for servo in self._listening(servo_id, now_ns):
                    servo.note_traffic(now_ns)
                    servo.write(address, data, now_ns)
                k += 5 + length
            return []
        if instruction == p.FACTORY_RESET and params[:1] == b"\xff":
            return []  # a broadcast reset of everything, IDs included, is refused
        if instruction in (p.WRITE, p.REG_WRITE, p.ACTION, p.REBOOT, p.CLEAR, p.FACTORY_RESET):
            for servo in [s for s in self.servos if s.hears(now_ns, self.baud)]:
                servo.execute(instruction, params, now_ns)
        return []

    def _group_read(
        self, instruction: int, entries: list[tuple[int, int, int]], now_ns: int
    ) -> list[_Pending]:
        fast = instruction in (p.FAST_SYNC_READ, p.FAST_BULK_READ)
        answers: list[tuple[Servo, int, Result, int]] = []
        for servo_id, address, length in entries:
            hearing = self._listening(servo_id, now_ns)
            if not hearing:
                continue
            servo = hearing[0]
            servo.note_traffic(now_ns)
            if not servo.replies_to(instruction) or (fast and not servo.supports_fast_read):
                continue
            answers.append((servo, servo_id, servo.read(address, length, now_ns), length))
        if not fast:
            return [self._status(servo, result) for servo, _, result, _ in answers]
        if not answers or answers[0][1] in self.faults.muted:
            return []  # the first servo sends the header: without it there is no packet
        # Each servo drives its own part of the combined packet: a muted one leaves a hole, so the
        # packet falls short of its announced length and the host's read fails.
        parts = [
            (servo.status_error(result.error), sid, result.params if not result.error else bytes(length))
            for servo, sid, result, length in answers
            if sid not in self.faults.muted
        ]
        announced = 1 + sum(length + 4 for _, _, length in entries)
        packet = p.build_fast_status(parts, announced_length=announced)
        return [_Pending(answers[0][0], packet, p.BROADCAST_ID)]
