"""What the runner emits while it runs, handed to the run's sinks: phases, commands, notes, per-tick rows.

The recorder knows the sinks only as `rig.runner.sinks.RunSink`s. A run whose log cannot be written
(a sink raises `LogWriteError`) stops (a fault), except inside the safe state, where logging is best
effort: the first failure ends logging and the release goes on (`best_effort`). Warnings and errors
also go out as one-line messages for people, which still go out when the log does not.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from rig.hw.seams import Clock, LoadCellSample, ServoState
from rig.log.format import schemas
from rig.log.writing.writer import LogWriteError
from rig.records import (
    Estimate,
    LogLevel,
    LogMessage,
    ServoCommand,
    ServoCommandName,
    TrialPhase,
    TrialResult,
    TrialState,
)
from rig.runner.phases import PhaseMachine
from rig.runner.sinks import RunSink
from rig.vocabulary import ServoRole


class RunRecorder:
    """Emits the run to its sinks, and keeps the phase machine whose changes it logs."""

    def __init__(self, sinks: Sequence[RunSink], clock: Clock, roles: Mapping[int, ServoRole]) -> None:
        self.sinks = tuple(sinks)
        self.clock = clock
        self.roles = roles
        # Only these are offered the per-tick rows; with none, the runner does not build them.
        self._tick_sinks = tuple(sink for sink in self.sinks if sink.wants_ticks)
        self.phases = PhaseMachine()
        self.failed: LogWriteError | None = None
        self._best_effort = False

    @property
    def wants_ticks(self) -> bool:
        """Whether a sink takes the per-tick rows (and the link scenes) and logging still works."""
        return bool(self._tick_sinks) and self.failed is None

    def write(self, topic: str, payload: Mapping[str, Any], time_ns: int | None = None) -> None:
        """Log one message (now, unless `time_ns` is given); nothing once the log has failed."""
        if self.failed is not None:
            return
        at_ns = self.clock.time_ns() if time_ns is None else time_ns
        try:
            for sink in self.sinks:
                sink.log(topic, at_ns, payload)
        except LogWriteError as exc:
            self.logger_failed(exc)

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        states: dict[int, ServoState],
    ) -> None:
        """One tick's load-cell samples (tare-corrected) and servo states."""
        if self.failed is not None:
            return
        try:
            for sink in self._tick_sinks:
                sink.tick_rows(samples, states, self.roles)
        except LogWriteError as exc:
            self.logger_failed(exc)

    def trial_started(self, trial_id: int, description: str) -> None:
        """A trial begins."""
        for sink in self.sinks:
            sink.trial_started(trial_id, description)

    def trial_finished(self, result: TrialResult, estimate: Estimate) -> None:
        """A trial ended (its result and the estimate after it are logged by the runner)."""
        for sink in self.sinks:
            sink.trial_finished(result, estimate)

    def message(self, text: str) -> None:
        """A one-line event for people."""
        for sink in self.sinks:
            sink.message(text)

    def flush(self) -> None:
        """Wait until everything logged so far is written (end of a trial)."""
        try:
            for sink in self.sinks:
                sink.flush()
        except LogWriteError as exc:
            self.logger_failed(exc)

    def logger_failed(self, exc: LogWriteError) -> None:
        """The log cannot be written: stop logging; outside the safe state, stop the run (a fault)."""
        self.failed = exc
        self.message(f"log write failed, logging stopped: {exc}")
        if not self._best_effort:
            raise exc

    @contextlib.contextmanager
    def best_effort(self) -> Iterator[None]:
        """Inside, a failing log never stops the rig: the first failure ends logging (the safe state)."""
        self._best_effort = True
        try:
            yield
        finally:
            self._best_effort = False

    def command(self, servo_id: int, command: ServoCommandName, value: float | None, unit: str) -> None:
        """A command sent to a servo."""
        role = self.roles.get(servo_id, "")
        self.write(schemas.SERVO_COMMAND, ServoCommand(servo_id, role, command, value, unit).to_payload())

    def phase(
        self, phase: TrialPhase, trial_id: int | None, step: str | None = None, at_ns: int | None = None
    ) -> None:
        """Change phase (RuntimeError for a transition that would skip a safety step); logged if new."""
        if self.phases.to(phase):
            self.write(schemas.TRIAL_STATE, TrialState(trial_id, phase, step).to_payload(), at_ns)

    def phase_quiet(self, phase: TrialPhase, trial_id: int | None) -> None:
        """Best-effort phase change during cleanup (never raises)."""
        with contextlib.suppress(RuntimeError):
            self.phase(phase, trial_id, "safe_state")

    def note(self, level: LogLevel, text: str) -> None:
        """A line on `/rig/log`; warnings and errors also as a one-line message for people."""
        # The log itself may be what failed; the one-line message below still tells.
        with contextlib.suppress(Exception):
            now = self.clock.time_ns()
            self.write(schemas.LOG, LogMessage(now, level, text).to_payload(), now)
        if level >= LogLevel.WARNING:
            self.message(text)

    def announce(self, text: str, warning: bool = False) -> None:
        """A line for the log (`/rig/log`, INFO or WARNING) that also goes out as a one-line message."""
        self.note(LogLevel.WARNING if warning else LogLevel.INFO, text)
        if not warning:  # a warning is shown by `note` already
            self.message(text)
