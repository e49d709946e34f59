"""Where a run's output goes: the `RunSink` protocol and the sinks `rig run` and `rig study` use.

A run emits, in order: its start, the metadata and attachments, then while it runs the logged
messages (phases, commands, notes, trial results, estimates, link scenes), the per-tick rows, the
trials' starts and ends and one-line messages for people, a flush after every trial, and at its
end each sink's closing note and `stop`. It hands each of these to every sink it was given and
knows none of them, as a RunEngine emits documents to its subscribers: the MCAP file (`McapSink`),
the live view (`LiveSink`), the progress display (`rig.runner.progress`); `rig study` gives none.

A sink that does not want the per-tick rows (`wants_ticks` False) is never offered them; when no
sink wants them the runner does not build them.
"""

from __future__ import annotations

import os
import pickle
from collections.abc import Mapping
from operator import attrgetter
from typing import Any, Protocol

from rig.hw.seams import Clock, LoadCellSample, ServoState
from rig.log.format import schemas
from rig.log.live.publisher import LivePublisher
from rig.log.writing.writer import RunLogger
from rig.records import Estimate, LogLevel, LogMessage, TrialResult
from rig.vocabulary import ServoRole

# The load-cell log columns, taken without a Python-level call per sample.
_TIME_NS, _SEQ, _RAW = attrgetter("time_ns"), attrgetter("seq"), attrgetter("raw")
_FORCE_N, _DEVICE_TIME_US = attrgetter("force_n"), attrgetter("device_time_us")


class RunSink(Protocol):
    """What receives a run's output (see the module docstring)."""

    wants_ticks: bool  # offer it the per-tick rows (the load cell's samples, the servos' states)

    def start(self, run_id: str, total: int, done: int) -> None:
        """The run begins (or resumes with `done` of its `total` trials already complete)."""
        ...

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record of the run (session, protocol, rig, the simulator's truth at the end)."""
        ...

    def attachment(self, name: str, media_type: str, data: bytes) -> None:
        """A file the run carries (the protocol and rig YAML, the session's calibration files)."""
        ...

    def log(self, topic: str, time_ns: int, payload: Mapping[str, Any]) -> None:
        """One message of a `rig.log.schemas` topic, sampled at `time_ns`."""
        ...

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        states: Mapping[int, ServoState],
        roles: Mapping[int, ServoRole],
    ) -> None:
        """One tick's load-cell samples (tare-corrected: the force the log records) and servo states."""
        ...

    def trial_started(self, trial_id: int, description: str) -> None:
        """A trial begins."""
        ...

    def trial_finished(self, result: TrialResult, estimate: Estimate) -> None:
        """A trial ended with `result`; `estimate` is the run's estimate after it."""
        ...

    def message(self, text: str) -> None:
        """A one-line event for people (interlock, prompt, warning)."""
        ...

    def flush(self) -> None:
        """Make everything received so far durable or visible (the end of a trial)."""
        ...

    def closing_note(self, time_ns: int) -> LogMessage | None:
        """What this sink has to say of itself as the run ends, logged to every sink before `stop`."""
        ...

    def stop(self) -> None:
        """The run ended (whatever the reason); nothing more is sent."""
        ...


class NullSink:
    """Takes everything and keeps nothing; a sink that cares about a part overrides that part."""

    wants_ticks: bool = False

    def start(self, run_id: str, total: int, done: int) -> None:
        pass

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        pass

    def attachment(self, name: str, media_type: str, data: bytes) -> None:
        pass

    def log(self, topic: str, time_ns: int, payload: Mapping[str, Any]) -> None:
        pass

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        states: Mapping[int, ServoState],
        roles: Mapping[int, ServoRole],
    ) -> None:
        pass

    def trial_started(self, trial_id: int, description: str) -> None:
        pass

    def trial_finished(self, result: TrialResult, estimate: Estimate) -> None:
        pass

    def message(self, text: str) -> None:
        pass

    def flush(self) -> None:
        pass

    def closing_note(self, time_ns: int) -> LogMessage | None:
        return None

    def stop(self) -> None:
        pass


class McapSink(NullSink):
    """The run's MCAP file (`rig.log.writing.writer.RunLogger`); its failures raise `LogWriteError`."""

    wants_ticks = True

    def __init__(
        self, path: str | os.PathLike[str], clock: Clock, *, max_file_bytes: int | None = None
    ) -> None:
        self.logger = RunLogger(path, clock=clock, max_file_bytes=max_file_bytes)

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        self.logger.add_metadata(name, data)

    def attachment(self, name: str, media_type: str, data: bytes) -> None:
        self.logger.add_attachment(name, media_type, data)

    def log(self, topic: str, time_ns: int, payload: Mapping[str, Any]) -> None:
        self.logger.log(topic, time_ns, payload)

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        states: Mapping[int, ServoState],
        roles: Mapping[int, ServoRole],
    ) -> None:
        log = self.logger
        if samples:
            # One column per `schemas.LoadCellRow` field, by name: no dict or object per sample.
            log.log_columns(
                schemas.LOADCELL,
                map(_TIME_NS, samples),
                seq=map(_SEQ, samples),
                raw=map(_RAW, samples),
                force_n=map(_FORCE_N, samples),
                device_time_us=map(_DEVICE_TIME_US, samples),
            )
        for state in states.values():
            log.log(
                schemas.SERVO_STATE,
                state.time_ns,
                schemas.servo_state_payload(state, roles.get(state.servo_id, "")),
            )

    def flush(self) -> None:
        self.logger.flush(wait=True)

    def stop(self) -> None:
        self.logger.finish()


# The live view gets what it is sent in batches: at most this many messages, or this much log time.
LIVE_BATCH_MESSAGES = 1024
LIVE_BATCH_LOG_TIME_NS = 250_000_000


class LiveSink(NullSink):
    """The live view (`rig.log.live.LivePublisher`): the run's messages, batched, while a client subscribes.

    Nothing is built or sent while no client subscribes to anything. At the end its counts of
    published and dropped messages are its closing note (a warning if any were dropped).
    """

    wants_ticks = True

    def __init__(self, publisher: LivePublisher) -> None:
        self.publisher = publisher
        self._batch: list[tuple[str, int, int, Any]] = []
        self._batch_start_ns = 0

    def log(self, topic: str, time_ns: int, payload: Mapping[str, Any]) -> None:
        if self.publisher.has_subscribers:
            self._add([(topic, time_ns, time_ns, payload)])

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        states: Mapping[int, ServoState],
        roles: Mapping[int, ServoRole],
    ) -> None:
        if not self.publisher.has_subscribers:
            return
        rows: list[tuple[str, int, int, Any]] = [
            (schemas.LOADCELL, s.time_ns, s.time_ns, (s.seq, s.raw, s.force_n, s.device_time_us))
            for s in samples  # the payload in the loadcell row's field order
        ]
        rows += [
            (
                schemas.SERVO_STATE,
                state.time_ns,
                state.time_ns,
                schemas.servo_state_payload(state, roles.get(state.servo_id, "")),
            )
            for state in states.values()
        ]
        self._add(rows)

    def _add(self, messages: list[tuple[str, int, int, Any]]) -> None:
        if not messages:
            return
        if not self._batch:
            self._batch_start_ns = messages[0][1]
        self._batch += messages
        if (
            len(self._batch) >= LIVE_BATCH_MESSAGES
            or messages[-1][1] - self._batch_start_ns >= LIVE_BATCH_LOG_TIME_NS
        ):
            self.flush()

    def flush(self) -> None:
        if self._batch:
            batch, self._batch = self._batch, []
            self.publisher.publish_pickled(
                pickle.dumps(("batch", batch), protocol=pickle.HIGHEST_PROTOCOL), len(batch)
            )

    def closing_note(self, time_ns: int) -> LogMessage | None:
        self.flush()
        stats = self.publisher.close()
        level = LogLevel.WARNING if stats.dropped or stats.slow_client_events else LogLevel.INFO
        return LogMessage(time_ns, level, stats.text())
