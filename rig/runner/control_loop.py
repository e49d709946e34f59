"""The control loop: one tick per control period reads everything, logs it and checks the interlocks.

A tick waits for its period, reads the servo states (one sync read), drains the load cell (never
blocking), hands both to the recorder and checks the interlocks; the steps read what the tick saw
(`states`, `tick_samples`, `force_n`) and wait with `ticks_for` / `wait_until`. The safe state's
release does not tick here: it keeps its own readings (`rig.safety.release`) and hands them back
when it ends (`adopt`).

Two things the loop sees about time are logged, not absorbed: a tick that starts more than a
tenth of a period after its scheduled time is late (counted per trial in `/rig/trial/links`
`control`; one late by a whole period or more is a warning with its lateness and its likely
cause: the servo port's USB latency timer when the driver read one above 1 ms at connect, else
the host), and a Bus
Watchdog trip that the driver found and cleared after a quiet bus (a warning; the trial is void,
raised as `BusWatchdogTripped`, and repeated as after any device fault that clears).
"""

from __future__ import annotations

import operator
from collections.abc import Callable
from dataclasses import dataclass

from rig.errors import BusWatchdogTripped, InterlockTripped, StepTimeoutError
from rig.hw.seams import LoadCellSample, PortLatencySource, ServoState, WatchdogTripSource
from rig.hw.session import RigSession
from rig.hw.usb_latency import is_slow, latency_timer_cause
from rig.records import ControlTickStats, LogLevel
from rig.runner.recorder import RunRecorder
from rig.safety.interlocks import CurrentAtLimit, ForceCeiling, ServoHealth

# A tick is late when it starts more than this fraction of a period after its scheduled time.
LATE_TICK_FRACTION = 0.1
# Warnings for late ticks: one per tick late by at least a period, up to this many per trial.
MAX_LATE_TICK_NOTES = 10

_FORCE_N = operator.attrgetter("force_n")


def tare_corrected(samples: list[LoadCellSample], tare_n: float) -> list[LoadCellSample]:
    """Each sample with the tare taken off its force: the one shape a sample has up to the log."""
    return [LoadCellSample(s.time_ns, s.raw, s.force_n - tare_n, s.seq, s.device_time_us) for s in samples]


@dataclass(frozen=True)
class Reading:
    """What the last tick saw: every servo's state, the tare-corrected samples, the latest tension."""

    states: dict[int, ServoState]
    tick_samples: list[LoadCellSample]
    force_n: float


class ControlLoop:
    """Ticks at the protocol's control period; holds what the last tick read."""

    def __init__(
        self,
        session: RigSession,
        recorder: RunRecorder,
        *,
        period_s: float,
        ceiling: ForceCeiling,
        current_limit: CurrentAtLimit,
    ) -> None:
        self.session = session
        self.clock = session.clock
        self.recorder = recorder
        self.period_ns = round(period_s * 1e9)
        self.ceiling = ceiling
        self.health = ServoHealth(dict(session.roles))
        self.current_limit = current_limit
        self._next_tick_ns = 0
        self.tare_n = 0.0
        self.force_n = 0.0  # latest tare-corrected tension
        self.states: dict[int, ServoState] = {}
        self.tick_samples: list[LoadCellSample] = []  # this tick's samples, tare-corrected
        self._ticks = 0
        # The servos' watchdog-trip side, found once per servo object (a Protocol isinstance each
        # tick cost about 1 % of a simulated run, benchmarks/bench_runner.py).
        self._trip_servos: object = None
        self._trip_source: WatchdogTripSource | None = None
        self._late_ticks = 0
        self._max_lateness_ns = 0
        self._total_lateness_ns = 0
        self._late_notes = 0
        self.slow_latency_timer_ms: int | None = None  # the servo port's, when above 1 ms (at connect)

    def restart_pacing(self) -> None:
        """Count the next period from now (after connecting, or after a pause outside the loop)."""
        self._next_tick_ns = self.clock.monotonic_ns()

    def tick(self, *, interlocks: bool = True) -> None:
        """One control period: wait, read everything, log it, check the interlocks (unless told not to)."""
        if self.recorder.failed is not None:
            raise self.recorder.failed  # a run whose log cannot be written stops (a fault)
        self._next_tick_ns += self.period_ns
        now = self.clock.monotonic_ns()
        self._ticks += 1
        slept = self._next_tick_ns > now
        if slept:
            self.clock.sleep((self._next_tick_ns - now) / 1e9)
            now = self.clock.monotonic_ns()
        lateness_ns = now - self._next_tick_ns
        self._late(lateness_ns)
        if (lateness_ns > 0 and not slept) or lateness_ns >= self.period_ns:
            self._next_tick_ns = now  # late: do not try to catch up with a burst of ticks
        self.states = self.session.servos.read_states()
        tripped = self.watchdog_trips()
        samples = self.session.load_cell.poll()
        self.ingest(samples)
        if tripped is not None:
            # The trial ends here, so no next tick will start late and say so: count now the lateness
            # it would start with (a host paused during this tick's reads is what trips the watchdog).
            self._late(self.clock.monotonic_ns() - self._next_tick_ns - self.period_ns)
            raise tripped
        if interlocks:
            self.check_interlocks()

    def check_port_latency(self) -> None:
        """After the servos connect: warn once when their port's USB latency timer is above 1 ms.

        A bus that reports no timer (`PortLatencySource`: its port has none) leaves late ticks
        blamed on the host, as before.
        """
        servos = self.session.servos
        latency_ms = servos.latency_timer_ms if isinstance(servos, PortLatencySource) else None
        if latency_ms is None or not is_slow(latency_ms):
            self.slow_latency_timer_ms = None
            return
        self.slow_latency_timer_ms = latency_ms
        self.recorder.note(
            LogLevel.WARNING,
            f"{latency_timer_cause(latency_ms)}: every servo bus transaction may wait that long, so "
            "control ticks will start late and replies may time out",
        )

    def lateness_cause(self) -> str:
        """Why ticks run late, as far as the loop knows: a slow latency timer, else the host."""
        if self.slow_latency_timer_ms is not None:
            return latency_timer_cause(self.slow_latency_timer_ms)
        return "the host did not run in time (load, a slow disk, a suspend)"

    def _late(self, lateness_ns: int) -> None:
        """Count a late tick; a tick late by a whole period or more (one was skipped) is a warning.

        Late means starting more than `LATE_TICK_FRACTION` of a period after the scheduled time
        (a sleep's usual overshoot on a real host is not lateness).
        """
        if lateness_ns <= LATE_TICK_FRACTION * self.period_ns:
            return
        self._late_ticks += 1
        self._total_lateness_ns += lateness_ns
        self._max_lateness_ns = max(self._max_lateness_ns, lateness_ns)
        if lateness_ns >= self.period_ns and self._late_notes < MAX_LATE_TICK_NOTES:
            self._late_notes += 1
            self.recorder.note(
                LogLevel.WARNING,
                f"control tick late by {lateness_ns / 1e6:.1f} ms (period {self.period_ns / 1e6:g} ms): "
                + self.lateness_cause(),
            )

    def watchdog_trips(self) -> BusWatchdogTripped | None:
        """Log the Bus Watchdog trips the driver cleared on this read; the error that voids the trial."""
        servos = self.session.servos
        if servos is not self._trip_servos:
            self._trip_servos = servos
            self._trip_source = servos if isinstance(servos, WatchdogTripSource) else None
        source = self._trip_source
        if source is None:
            return None
        trips = source.take_watchdog_trips()
        for trip in trips:
            self.recorder.note(LogLevel.WARNING, trip.describe())
        if not trips:
            return None
        return BusWatchdogTripped("; ".join(trip.describe() for trip in trips))

    def take_tick_stats(self) -> ControlTickStats:
        """The ticks since the last call (a trial's, when called at its start and end); resets them."""
        stats = ControlTickStats(
            ticks=self._ticks,
            late_ticks=self._late_ticks,
            max_lateness_us=self._max_lateness_ns // 1000,
            total_lateness_us=self._total_lateness_ns // 1000,
        )
        self._ticks = self._late_ticks = self._max_lateness_ns = self._total_lateness_ns = 0
        self._late_notes = 0
        return stats

    def check_interlocks(self) -> None:
        """Raise InterlockTripped if this tick's samples or servo states trip an interlock."""
        now_ns = self.clock.monotonic_ns()
        reason = (
            self.ceiling.check(max(map(_FORCE_N, self.tick_samples), default=self.force_n))
            or self.health.check(self.states)
            or self.current_limit.check(self.states, now_ns)
        )
        if reason is not None:
            raise InterlockTripped(reason)

    def ingest(self, samples: list[LoadCellSample]) -> None:
        """Take one read's samples (tare-corrected) and log them with the servo states."""
        self.tick_samples = tare_corrected(samples, self.tare_n)
        if samples:
            self.force_n = self.tick_samples[-1].force_n
        self.recorder.tick_rows(self.tick_samples, self.states)

    def reading(self) -> Reading:
        """A copy of what the last tick saw (for the release, which must not share it)."""
        return Reading(dict(self.states), list(self.tick_samples), self.force_n)

    def adopt(self, reading: Reading) -> None:
        """Take over what the release read last, so the next tick and fault checks start from it."""
        self.states = reading.states
        self.tick_samples = reading.tick_samples
        self.force_n = reading.force_n

    def ticks_for(self, seconds: float) -> None:
        """Tick for `seconds`."""
        end = self.clock.monotonic_ns() + round(seconds * 1e9)
        while self.clock.monotonic_ns() < end:
            self.tick()

    def wait_until(
        self, done: Callable[[], bool], timeout_s: float, what: str, step: Callable[[], None] | None = None
    ) -> None:
        """Call `step` (a control tick by default) until `done()`; StepTimeoutError after `timeout_s`."""
        step = step or self.tick
        deadline = self.clock.monotonic_ns() + round(timeout_s * 1e9)
        while not done():
            if self.clock.monotonic_ns() > deadline:
                raise StepTimeoutError(f"step {what} did not finish within its timeout of {timeout_s:.1f} s")
            step()
