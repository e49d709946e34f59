"""What the runner writes while it runs: phase changes, servo commands, notes, per-tick rows.

A run whose log cannot be written stops (a fault), except inside the safe state, where logging is
best effort: the first failure ends logging and the release goes on (`best_effort`). Warnings and
errors also reach the progress display, which still works when the log does not.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from operator import attrgetter, itemgetter

from rig.hw.seams import Clock, LoadCellSample, ServoState
from rig.log.format import schemas
from rig.log.writing.writer import LogWriteError, RunLogger
from rig.records import LogLevel, LogMessage, ServoCommand, ServoCommandName, TrialPhase, TrialState
from rig.runner.phases import PhaseMachine
from rig.runner.progress import ProgressReporter
from rig.vocabulary import ServoRole

# The load-cell log columns, taken without a Python-level call per sample.
_FIRST, _SECOND = itemgetter(0), itemgetter(1)
_SEQ, _RAW, _DEVICE_TIME_US = attrgetter("seq"), attrgetter("raw"), attrgetter("device_time_us")


class RunRecorder:
    """The run's log and progress lines, and the phase machine whose changes it logs."""

    def __init__(
        self,
        logger: RunLogger,
        clock: Clock,
        progress: ProgressReporter,
        roles: Mapping[int, ServoRole],
        *,
        log_ticks: bool = True,
    ) -> None:
        self.log = logger
        self.clock = clock
        self.progress = progress
        self.roles = roles
        # False for a logger that keeps nothing (`rig study`'s): the per-tick rows are then not built.
        self.log_ticks = log_ticks
        self.phases = PhaseMachine()
        self.failed: LogWriteError | None = None
        self._best_effort = False

    def write(self, topic: str, payload: dict[str, object], time_ns: int | None = None) -> None:
        """Log one message (now, unless `time_ns` is given); nothing once the log has failed."""
        if self.failed is not None:
            return
        try:
            self.log.log(topic, self.clock.time_ns() if time_ns is None else time_ns, payload)
        except LogWriteError as exc:
            self.logger_failed(exc)

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        tick_samples: list[tuple[int, float]],
        states: dict[int, ServoState],
    ) -> None:
        """One tick's load-cell samples (with their tare-corrected forces) and servo states."""
        if self.failed is not None or not self.log_ticks:
            return
        try:
            if samples:
                # One column per `schemas.ROW_FIELDS` field, by name: no dict or object per sample.
                self.log.log_columns(
                    schemas.LOADCELL,
                    map(_FIRST, tick_samples),
                    seq=map(_SEQ, samples),
                    raw=map(_RAW, samples),
                    force_n=map(_SECOND, tick_samples),
                    device_time_us=map(_DEVICE_TIME_US, samples),
                )
            roles = self.roles
            for state in states.values():
                self.log.log(
                    schemas.SERVO_STATE,
                    state.time_ns,
                    schemas.servo_state_payload(state, roles.get(state.servo_id, "")),
                )
        except LogWriteError as exc:
            self.logger_failed(exc)

    def flush(self) -> None:
        """Wait until everything logged so far is written (end of a trial)."""
        try:
            self.log.flush(wait=True)
        except LogWriteError as exc:
            self.logger_failed(exc)

    def logger_failed(self, exc: LogWriteError) -> None:
        """The log cannot be written: stop logging; outside the safe state, stop the run (a fault)."""
        self.failed = exc
        self.progress.message(f"log write failed, logging stopped: {exc}")
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
        """A line on `/rig/log`; warnings and errors go to the progress display too."""
        # The log itself may be what failed; the progress line below still tells.
        with contextlib.suppress(Exception):
            now = self.clock.time_ns()
            self.write(schemas.LOG, LogMessage(now, level, text).to_payload(), now)
        if level >= LogLevel.WARNING:
            self.progress.message(text)

    def announce(self, text: str, warning: bool = False) -> None:
        """A line for the log (`/rig/log`, INFO or WARNING) that the progress display shows too."""
        self.note(LogLevel.WARNING if warning else LogLevel.INFO, text)
        if not warning:  # a warning is shown by `note` already
            self.progress.message(text)
