"""The run logger: a queued MCAP writer whose compression and file I/O run on their own thread.

The acquisition loop calls `RunLogger.log(topic, log_time_ns, payload)`, which only timestamps the
call (publish time) and enqueues; JSON serialization, chunking, zstd and writes happen on the
writer thread. The thread closes the open chunk (flush) about every second of log time or wall
time and whenever the runner asks (`flush()`, after every trial), so a crash loses at most that
much. An error on the writer thread is never lost: it is re-raised as `LogWriteError` by the next
call into the logger, or by `finish()`.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import operator
import os
import queue
import threading
import time
import weakref
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer
from mcap.writer import __version__ as MCAP_VERSION

import rig
from rig.errors import RigError, RigTimeoutError
from rig.hw.seams import Clock
from rig.log import schemas

LIBRARY = f"rig-logger/{rig.__version__} mcap-python/{MCAP_VERSION}"
DEFAULT_CHUNK_SIZE = 512 * 1024  # uncompressed bytes; periodic flushes usually close chunks first
DEFAULT_FLUSH_INTERVAL_S = 1.0
DEFAULT_MAX_PENDING = 100_000  # queued messages (~80 s of rig data) before log() applies back-pressure
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_STRICT_ENV = "RIG_LOG_STRICT"


class LogWriteError(RigError):
    """The writer thread could not serialize or write something; the message says what."""


@dataclass
class _Control:
    """A request to the writer thread, processed in order with the messages."""

    op: str  # "flush", "metadata", "attachment", "finish"
    args: tuple[Any, ...] = ()
    done: threading.Event = field(default_factory=threading.Event)


_live_loggers: weakref.WeakSet[RunLogger] = weakref.WeakSet()


@atexit.register
def _finish_live_loggers() -> None:  # pragma: no cover - runs at interpreter exit
    for logger in list(_live_loggers):
        with contextlib.suppress(Exception):  # nothing left to report to at exit
            logger.finish()


class RunLogger:
    """Log rig topics to one MCAP file from any thread; the writing happens on a dedicated thread.

    :param path: the file to create; an existing file is never overwritten (`FileExistsError`).
    :param clock: where publish times come from (`clock.time_ns()` at enqueue); the system clock
        if None.
    :param chunk_size: uncompressed bytes at which a chunk is closed.
    :param compression: "zstd", "lz4" or "none".
    :param flush_interval_s: close the open chunk after this much log time or wall time.
    :param strict: check every payload against its schema in `log()` (slow; for tests). None reads
        the environment variable RIG_LOG_STRICT ("1" enables).
    :param max_pending: queued messages above which `log()` waits for the writer to catch up.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        clock: Clock | None = None,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        strict: bool | None = None,
        max_pending: int = DEFAULT_MAX_PENDING,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(f"compression: {compression!r} not allowed; allowed: {', '.join(_COMPRESSION)}")
        if chunk_size <= 0 or flush_interval_s <= 0 or max_pending <= 0:
            raise ValueError("chunk_size, flush_interval_s and max_pending must be positive")
        self.path = Path(path)
        self._now_ns: Callable[[], int] = clock.time_ns if clock is not None else time.time_ns
        self._strict = os.environ.get(_STRICT_ENV) == "1" if strict is None else strict
        self._flush_interval_ns = round(flush_interval_s * 1e9)
        self._max_pending = max_pending
        self._queue: queue.SimpleQueue[tuple[str, int, int, Mapping[str, Any]] | _Control] = (
            queue.SimpleQueue()
        )
        self._errors: list[BaseException] = []  # appended by the writer thread, popped by callers
        self._fatal: BaseException | None = None  # the writer thread stopped writing
        self._finish_lock = threading.Lock()
        self._finished = False
        self.messages_logged = 0  # enqueued by log()

        self._file = open(self.path, "xb")  # noqa: SIM115 - closed by the writer thread
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=_COMPRESSION[compression])
            self._writer.start(profile="", library=LIBRARY)
            self._file.flush()
        except BaseException:
            self._file.close()
            raise
        self._channels: dict[str, int] = {}  # topic -> channel id; writer thread only
        self._sequences: dict[int, int] = {}
        self._thread = threading.Thread(target=self._run, name=f"rig-logger {self.path.name}", daemon=True)
        self._thread.start()
        _live_loggers.add(self)

    # -- caller side -------------------------------------------------------------------------

    def log(self, topic: str, log_time_ns: int, payload: Mapping[str, Any]) -> None:
        """Enqueue one message; never waits on compression or I/O.

        `log_time_ns` is the epoch time of sampling. `payload` must not be changed afterwards (the
        builders in `rig.log.schemas` return fresh dicts).
        """
        if self._errors or self._fatal is not None:
            self._raise_errors()
        if self._finished:
            raise LogWriteError(f"{self.path}: log() after finish()")
        if topic not in schemas.TOPICS:
            raise KeyError(f"unknown topic {topic!r}; known: {', '.join(schemas.TOPICS)}")
        if type(log_time_ns) is not int:
            log_time_ns = operator.index(log_time_ns)  # numpy ints are fine, floats are not
        if self._strict:
            schemas.check_payload(topic, payload)
        self._queue.put((topic, log_time_ns, self._now_ns(), payload))
        self.messages_logged += 1
        if self._queue.qsize() > self._max_pending:
            self._wait_for_drain()

    def flush(self, *, wait: bool = True, fsync: bool = False, timeout_s: float = 30.0) -> None:
        """Close the open chunk and flush the file; with `wait`, return once that is done.

        With `fsync` the data also reaches the disk (survives a power loss).
        """
        self._check_open("flush")
        request = _Control("flush", (fsync,))
        self._queue.put(request)
        if wait:
            self._wait(request, timeout_s, "flush")
        if self._errors or self._fatal is not None:
            self._raise_errors()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Add a metadata record (a str -> str map), written in order with the messages."""
        self._check_open("add_metadata")
        bad = [k for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise TypeError(f"metadata {name!r}: keys and values must be strings; bad keys: {bad}")
        self._queue.put(_Control("metadata", (str(name), dict(data))))

    def add_attachment(
        self,
        name: str,
        media_type: str,
        data: bytes,
        *,
        log_time_ns: int | None = None,
        create_time_ns: int = 0,
    ) -> None:
        """Attach a file (e.g. the protocol YAML); `log_time_ns` defaults to now."""
        self._check_open("add_attachment")
        log_ns = self._now_ns() if log_time_ns is None else operator.index(log_time_ns)
        args = (operator.index(create_time_ns), log_ns, str(name), str(media_type), bytes(data))
        self._queue.put(_Control("attachment", args))

    def finish(self, timeout_s: float = 60.0) -> None:
        """Write everything queued, the summary and the footer, and close the file. Idempotent.

        Raises the first writer-thread error not yet reported.
        """
        with self._finish_lock:
            if not self._finished:
                self._finished = True
                request = _Control("finish")
                self._queue.put(request)
                self._wait(request, timeout_s, "finish")
                self._thread.join(timeout_s)
                _live_loggers.discard(self)
        if self._errors or self._fatal is not None:
            self._raise_errors()

    close = finish

    def __enter__(self) -> RunLogger:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc is None:
            self.finish()
            return
        with contextlib.suppress(LogWriteError):  # the exception already propagating is the one to report
            self.finish()

    @property
    def pending(self) -> int:
        """Messages and requests queued but not yet written."""
        return self._queue.qsize()

    def _check_open(self, what: str) -> None:
        if self._errors or self._fatal is not None:
            self._raise_errors()
        if self._finished:
            raise LogWriteError(f"{self.path}: {what}() after finish()")

    def _raise_errors(self) -> None:
        if self._errors:
            error = self._errors.pop(0)
            raise LogWriteError(f"{self.path}: {error}") from error
        if self._fatal is not None:
            raise LogWriteError(f"{self.path}: the logger stopped writing: {self._fatal!r}") from self._fatal

    def _wait(self, request: _Control, timeout_s: float, what: str) -> None:
        if not request.done.wait(timeout_s):
            raise RigTimeoutError(
                f"{self.path}: {what} not done after {timeout_s:g} s ({self.pending} queued)"
            )

    def _wait_for_drain(self) -> None:
        low_water = self._max_pending // 2
        while self._queue.qsize() > low_water and self._fatal is None and self._thread.is_alive():
            time.sleep(0.001)

    # -- writer thread -----------------------------------------------------------------------

    def _run(self) -> None:
        dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
        writer = self._writer
        get = self._queue.get
        interval_ns = self._flush_interval_ns
        last_flush_log_ns: int | None = None
        last_flush_wall_ns = time.monotonic_ns()
        unflushed = False
        item: object = None
        while True:
            try:
                timeout = None
                if unflushed:
                    timeout = max(0.0, (last_flush_wall_ns + interval_ns - time.monotonic_ns()) / 1e9)
                try:
                    item = get(timeout=timeout)
                except queue.Empty:
                    self._flush(fsync=False)
                    unflushed, last_flush_wall_ns = False, time.monotonic_ns()
                    continue
                if type(item) is tuple:
                    topic, log_ns, publish_ns, payload = item
                    channel_id = self._channels.get(topic)
                    if channel_id is None:
                        channel_id = self._register(topic)
                    try:
                        data = dumps(payload).encode()
                    except (ValueError, TypeError, OverflowError) as error:
                        self._errors.append(
                            LogWriteError(f"{topic} message at log time {log_ns} not written: {error}")
                        )
                        continue
                    sequence = self._sequences[channel_id] = (self._sequences[channel_id] + 1) & 0xFFFFFFFF
                    writer.add_message(channel_id, log_ns, data, publish_ns, sequence)
                    unflushed = True
                    now_wall_ns = time.monotonic_ns()
                    if last_flush_log_ns is None:
                        last_flush_log_ns = log_ns
                    if (
                        log_ns - last_flush_log_ns >= interval_ns
                        or now_wall_ns - last_flush_wall_ns >= interval_ns
                    ):
                        self._flush(fsync=False)
                        unflushed, last_flush_log_ns, last_flush_wall_ns = False, log_ns, now_wall_ns
                    continue
                if self._control(item):
                    return
                if item.op == "flush":
                    unflushed, last_flush_wall_ns = False, time.monotonic_ns()
            except BaseException as error:  # the file cannot be trusted any more: stop writing
                self._fatal = error
                if not (isinstance(item, _Control) and item.op == "finish"):
                    self._drain_after_fatal()
                return

    def _register(self, topic: str) -> int:
        spec = schemas.TOPICS[topic]
        schema_id = self._writer.register_schema(spec.schema_name, schemas.SCHEMA_ENCODING, spec.schema_bytes)
        channel_id = self._writer.register_channel(topic, schemas.MESSAGE_ENCODING, schema_id)
        self._channels[topic] = channel_id
        self._sequences[channel_id] = 0
        return channel_id

    def _flush(self, *, fsync: bool) -> None:
        self._writer.flush()
        if fsync:
            os.fsync(self._file.fileno())

    def _control(self, request: _Control) -> bool:
        """Carry out one request; True when the thread should end (finish)."""
        try:
            if request.op == "flush":
                self._flush(fsync=request.args[0])
            elif request.op == "metadata":
                self._writer.add_metadata(*request.args)
            elif request.op == "attachment":
                self._writer.add_attachment(*request.args)
            elif request.op == "finish":
                try:
                    self._writer.finish()
                    self._file.flush()
                    os.fsync(self._file.fileno())
                finally:
                    self._file.close()
                return True
        finally:
            request.done.set()
        return False

    def _drain_after_fatal(self) -> None:
        """Release every waiter; close the file (unfinished) when asked to finish."""
        with contextlib.suppress(Exception):  # the fatal error is what gets reported
            self._file.close()
        while True:
            item = self._queue.get()
            if isinstance(item, _Control):
                item.done.set()
                if item.op == "finish":
                    return
