"""Faults from a simulated rig config (`simulation.faults:`) applied to the emulated devices.

Rate faults are set up once: replies of the emulated servos lost, corrupted or delayed at random
(seeded), load-cell lines garbled or with bad checksums. Timed faults are events on the virtual
clock, `at_s` after the invocation's start and, with `duration_s`, undone after it:

* `silent` servo: its replies are lost but it still obeys (a broken return line);
* `disconnect` servo: it neither hears nor answers (a cut cable; its Bus Watchdog trips);
* `overload` servo: Hardware Error Status 0x20 latches and its torque drops, as a real overload;
* `gap` / `silent` load cell: no lines for `duration_s` / from then on (stale data);
* `disconnect` load cell: the host's serial port fails, as when a USB adapter is pulled out;
* `pause` host: the host stops running for `duration_s` (a slow disk, a laptop suspend) while the
  devices go on: virtual time jumps by that much with nothing said on the bus, so a pause longer
  than the servos' Bus Watchdog trips it.

Rate kinds (drop, corrupt, delay, garble, checksum) need `rate`; the others need `at_s`.

A `logger` `write_error` is not an event: it caps the log file (`RigSession.log_limit_bytes`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import assert_never

from rig.inputs.rig_config import RigConfig
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.kinds import (
    FaultDevice,
    HostFaultKind,
    LoadCellFaultKind,
    LoggerFaultKind,
    ReplyFaultKind,
    ServoFaultKind,
)
from rig.sim.loadcell.emulator import FaultPlan, LoadCellEmulator
from rig.sim.settings import FaultConfig
from rig.sim.virtual_clock import VirtualClock
from rig.vocabulary import ServoRole

OVERLOAD_BIT = 0x20
_FOREVER_S = 1e9


def loadcell_rate_faults(faults: tuple[FaultConfig, ...]) -> FaultPlan:
    """The load cell's per-line faults (built into the emulator when it is made)."""
    garbage = sum(f.rate or 0.0 for f in faults if f.kind is LoadCellFaultKind.GARBLE)
    checksum = sum(f.rate or 0.0 for f in faults if f.kind is LoadCellFaultKind.CHECKSUM)
    return FaultPlan(garbage_per_line=min(garbage, 1.0), bad_checksum_per_line=min(checksum, 1.0))


def log_limit_bytes(faults: tuple[FaultConfig, ...]) -> int | None:
    """The log-file cap of a `logger` `write_error` fault (the smallest if several)."""
    limits = [f.after_bytes for f in faults if f.device is FaultDevice.LOGGER and f.after_bytes is not None]
    return min(limits) if limits else None


@dataclass
class _Event:
    at_ns: int
    action: Callable[[], None]
    done: bool = False


class FaultSchedule:
    """The timed faults of one run, fired by the virtual clock (register after the world)."""

    def __init__(self) -> None:
        self._events: list[_Event] = []
        self.fired: list[str] = []

    def at(self, at_ns: int, what: str, action: Callable[[], None]) -> None:
        """Run `action` once the clock reaches `at_ns`."""

        def logged() -> None:
            self.fired.append(what)
            action()

        self._events.append(_Event(at_ns, logged))
        self._events.sort(key=lambda e: e.at_ns)

    @property
    def has_events(self) -> bool:
        """Whether any timed fault was scheduled (else the clock need not call this schedule)."""
        return bool(self._events)

    def advance_to(self, now_ns: int) -> None:
        """Clock listener: fire every event that is due."""
        for event in self._events:
            if event.at_ns > now_ns:
                break
            if not event.done:
                event.done = True
                event.action()


def apply_faults(
    config: RigConfig,
    faults: tuple[FaultConfig, ...],
    *,
    bus: EmulatedBus,
    loadcell: LoadCellEmulator,
    clock: VirtualClock,
    seed: int,
) -> FaultSchedule:
    """Set up every servo and load-cell fault of the config; returns the schedule of timed ones."""
    start_ns = clock.monotonic_ns()
    schedule = FaultSchedule()
    bus.faults.rng.seed(seed)
    for fault in faults:
        match fault.kind:
            case ServoFaultKind():
                for servo_id in _servo_ids(config, fault.device):
                    _servo_fault(fault, fault.kind, servo_id, bus, schedule, start_ns)
            case LoadCellFaultKind():
                _loadcell_fault(fault, fault.kind, loadcell, schedule, start_ns)
            case HostFaultKind.PAUSE:
                _host_pause(fault, clock, schedule, start_ns)
            case LoggerFaultKind.WRITE_ERROR:
                pass  # it caps the log file (`log_limit_bytes`)
            case _:
                assert_never(fault.kind)
    if schedule.has_events:
        clock.on_advance(schedule.advance_to)
    return schedule


def _servo_ids(config: RigConfig, device: FaultDevice) -> list[int | None]:
    if device is FaultDevice.SERVOS:
        return [None]
    role = ServoRole(device.value)  # `winch` and `bender` name a servo role
    return [s.servo_id for s in config.servos.servos if s.role is role]


def _window_ns(fault: FaultConfig, start_ns: int) -> tuple[int, int | None]:
    assert fault.at_s is not None
    begin = start_ns + round(fault.at_s * 1e9)
    end = None if fault.duration_s is None else begin + round(fault.duration_s * 1e9)
    return begin, end


def _servo_fault(
    fault: FaultConfig,
    kind: ServoFaultKind,
    servo_id: int | None,
    bus: EmulatedBus,
    schedule: FaultSchedule,
    start_ns: int,
) -> None:
    name = f"{fault.device} {kind}"
    if fault.rate is not None:
        delay_s = (fault.delay_ms or 0.0) / 1e3
        bus.faults.at_rate(_reply_fault(kind), fault.rate, servo_id, delay_s)
        return
    ids = bus.ids if servo_id is None else [servo_id]
    begin, end = _window_ns(fault, start_ns)
    for sid in ids:
        start, stop = _servo_actions(kind, sid, bus)
        schedule.at(begin, name, start)
        if end is not None and stop is not None:
            schedule.at(end, f"{name} ends", stop)


def _reply_fault(kind: ServoFaultKind) -> ReplyFaultKind:
    """The bus's reply fault of a servo fault at a rate (`parse_fault` allows a rate on these only)."""
    match kind:
        case ServoFaultKind.DROP:
            return ReplyFaultKind.DROP
        case ServoFaultKind.CORRUPT:
            return ReplyFaultKind.CORRUPT
        case ServoFaultKind.DELAY:
            return ReplyFaultKind.DELAY
        case ServoFaultKind.SILENT | ServoFaultKind.DISCONNECT | ServoFaultKind.OVERLOAD:
            raise ValueError(f"servo fault {kind} happens at a time, not at a rate")
        case _:
            assert_never(kind)


def _servo_actions(
    kind: ServoFaultKind, servo_id: int, bus: EmulatedBus
) -> tuple[Callable[[], None], Callable[[], None] | None]:
    """What starts a timed servo fault, and what ends it (None: it stays, as a latched error does)."""
    match kind:
        case ServoFaultKind.SILENT:
            return (lambda: bus.faults.mute(servo_id)), (lambda: bus.faults.mute(servo_id, False))
        case ServoFaultKind.DISCONNECT:
            return (lambda: bus.set_silent(servo_id)), (lambda: bus.set_silent(servo_id, False))
        case ServoFaultKind.OVERLOAD:
            return (lambda: bus.set_hardware_error(servo_id, OVERLOAD_BIT)), None
        case ServoFaultKind.DROP | ServoFaultKind.CORRUPT | ServoFaultKind.DELAY:
            raise ValueError(f"servo fault {kind} happens at a rate, not at a time")
        case _:
            assert_never(kind)


def _loadcell_fault(
    fault: FaultConfig,
    kind: LoadCellFaultKind,
    loadcell: LoadCellEmulator,
    schedule: FaultSchedule,
    start_ns: int,
) -> None:
    if fault.rate is not None:
        return  # built into the emulator (`loadcell_rate_faults`)
    begin, end = _window_ns(fault, start_ns)
    name = f"loadcell {kind}"
    match kind:
        case LoadCellFaultKind.GAP | LoadCellFaultKind.SILENT:
            duration_s = _FOREVER_S if end is None else (end - begin) / 1e9
            loadcell.inject_silence(duration_s, at_ns=begin)
            schedule.at(begin, name, lambda: None)
        case LoadCellFaultKind.DISCONNECT:

            def plug(unplugged: bool) -> Callable[[], None]:
                def act() -> None:
                    loadcell.unplugged = unplugged

                return act

            schedule.at(begin, name, plug(True))
            if end is not None:
                schedule.at(end, f"{name} ends", plug(False))
        case LoadCellFaultKind.GARBLE | LoadCellFaultKind.CHECKSUM:
            pass  # rate kinds (`parse_fault` gives them a rate)
        case _:
            assert_never(kind)


def _host_pause(fault: FaultConfig, clock: VirtualClock, schedule: FaultSchedule, start_ns: int) -> None:
    """The host stops for `duration_s` at `at_s`: the clock jumps while the host is in a wait."""
    begin, end = _window_ns(fault, start_ns)
    assert end is not None  # a pause has a duration (parse_fault)
    schedule.at(begin, "host pause", lambda: clock.advance_ns(end - begin))
