"""The run logger: a batched MCAP writer whose encoding, compression and file I/O run in a child process.

The acquisition loop calls `RunLogger.log(topic, log_time_ns, payload)`, which only timestamps the
call (publish time) and appends to a batch; batches go over a pipe to the writer process
(`rig.log.writing.writer_process`), which does the JSON serialization, chunking, zstd and writes without
sharing the acquisition loop's GIL. A batch is sent when it holds `BATCH_MESSAGES` messages or spans
`BATCH_LOG_TIME_NS` of log time, and before every flush, metadata, attachment and finish. The writer
process closes the open chunk (flush) about every second of log time or wall time and whenever the
runner asks (`flush()`, after every trial), so a crash loses at most that much; if this process
dies, the writer process leaves the file unfinished with every flushed chunk in it. An error in the
writer process is never lost: it is re-raised as `LogWriteError` by the next call into the logger,
or by `finish()`.
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import operator
import os
import pickle
import subprocess
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from mcap.writer import __version__ as MCAP_VERSION

import rig
from rig.errors import RigError, RigTimeoutError
from rig.hw.seams import Clock
from rig.log.child_process import start_child
from rig.log.format import schemas
from rig.log.writing.writer_process import COMPRESSION

LIBRARY = f"rig-logger/{rig.__version__} mcap-python/{MCAP_VERSION}"
DEFAULT_CHUNK_SIZE = 512 * 1024  # uncompressed bytes; periodic flushes usually close chunks first
DEFAULT_FLUSH_INTERVAL_S = 1.0
DEFAULT_MAX_PENDING = 100_000  # queued messages (~80 s of rig data) before log() applies back-pressure
BATCH_MESSAGES = 1024  # messages per pipe write (fewer when max_pending is small)
BATCH_LOG_TIME_NS = 250_000_000  # a batch spans at most this much log time
PIPE_BYTES = 1 << 20  # request pipe capacity, so that sending a batch does not wait for the writer
_STRICT_ENV = "RIG_LOG_STRICT"


class LogWriteError(RigError):
    """The writer process could not serialize or write something; the message says what."""


_live_loggers: weakref.WeakSet[RunLogger] = weakref.WeakSet()


@atexit.register
def _finish_live_loggers() -> None:  # pragma: no cover - runs at interpreter exit
    for logger in list(_live_loggers):
        with contextlib.suppress(Exception):  # nothing left to report to at exit
            logger.finish()


class RunLogger:
    """Log rig topics to one MCAP file from any thread; the writing happens in a child process.

    :param path: the file to create; an existing file is never overwritten (`FileExistsError`).
    :param clock: where publish times come from (`clock.time_ns()` at enqueue); the system clock
        if None.
    :param chunk_size: uncompressed bytes at which a chunk is closed.
    :param compression: "zstd", "lz4" or "none".
    :param flush_interval_s: close the open chunk after this much log time or wall time.
    :param strict: check every payload against its schema in `log()` (slow; for tests). None reads
        the environment variable RIG_LOG_STRICT ("1" enables).
    :param max_pending: queued messages above which `log()` waits for the writer to catch up.
    :param max_file_bytes: the most the file may hold; the writer's writes beyond it fail (as on a
        full disk) and the logger raises `LogWriteError`. None: no limit but the disk's.
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
        max_file_bytes: int | None = None,
    ) -> None:
        if compression not in COMPRESSION:
            raise ValueError(f"compression: {compression!r} not allowed; allowed: {', '.join(COMPRESSION)}")
        if chunk_size <= 0 or flush_interval_s <= 0 or max_pending <= 0:
            raise ValueError("chunk_size, flush_interval_s and max_pending must be positive")
        self.path = Path(path)
        self._now_ns: Callable[[], int] = clock.time_ns if clock is not None else time.time_ns
        self._strict = os.environ.get(_STRICT_ENV) == "1" if strict is None else strict
        self._max_pending = max_pending
        self._batch_limit = max(1, min(BATCH_MESSAGES, max_pending // 2))
        self._batch: list[tuple[str, int, int, Mapping[str, Any] | tuple[Any, ...]]] = []
        self._batch_start_ns = 0
        self._sent = 0  # messages sent to the writer process
        self._written = 0  # messages the writer process has handled (reader thread)
        self._progress = threading.Condition()
        self._tokens = itertools.count(1)
        self._done: dict[int, threading.Event] = {}  # request token -> set when answered
        self._errors: list[BaseException] = []  # appended by the reader thread, popped by callers
        self._fatal: BaseException | None = None  # the writer process stopped writing
        self._send_lock = threading.Lock()
        self._finish_lock = threading.Lock()
        self._finished = False
        self.messages_logged = 0  # accepted by log()

        file_fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        child = start_child(
            "rig.log.writing.writer_process",
            [
                LIBRARY,
                str(chunk_size),
                compression,
                str(round(flush_interval_s * 1e9)),
                str(max_file_bytes or 0),
            ],
            pipe_bytes=PIPE_BYTES,
            extra_fds=(file_fd,),
        )
        self._process = child.process
        request_write, reply_read = child.request_fd, child.reply_fd
        self._requests = Connection(request_write, readable=False)
        self._replies = Connection(reply_read, writable=False)
        self._send(schemas.topics_request())  # the schemas, so that the child need not build them
        self._reader = threading.Thread(
            target=self._read_replies, name=f"rig-logger {self.path.name}", daemon=True
        )
        self._reader.start()
        _live_loggers.add(self)

    # -- caller side -------------------------------------------------------------------------

    def log(self, topic: str, log_time_ns: int, payload: Mapping[str, Any]) -> None:
        """Enqueue one message; never waits on encoding, compression or I/O (unless back-pressure).

        `log_time_ns` is the epoch time of sampling. `payload` must not be changed afterwards (the
        builders in `rig.log.format.schemas` return fresh dicts). Rows go through `log_columns`.
        """
        self._enqueue(topic, ((log_time_ns, payload),), rows=False)

    def log_columns(self, topic: str, times_ns: Iterable[int], **columns: Iterable[Any]) -> None:
        """Enqueue one message per time of a row topic, from one column per field, named as the fields.

        The names must be exactly those of `schemas.ROW_FIELDS[topic]` (any order): a column under
        the wrong name is a `TypeError`, not a swapped field. The rows go to the writer process as
        plain tuples, without a dict per sample (one call per control period for the load-cell
        samples); the file holds the JSON object `log` would write for the row's payload. Strict mode
        checks each row field by field.
        """
        fields = schemas.ROW_FIELDS.get(topic)
        if fields is None or columns.keys() != set(fields):
            raise TypeError(f"{topic}: columns {sorted(columns)}; allowed: exactly the fields {fields}")
        rows = zip(*map(columns.__getitem__, fields), strict=True)
        self._enqueue(topic, zip(times_ns, rows, strict=True), rows=True)

    def _enqueue(
        self,
        topic: str,
        messages: Iterable[tuple[int, Mapping[str, Any] | tuple[Any, ...]]],
        *,
        rows: bool,
    ) -> None:
        """Add messages of one topic to the batch: payload mappings, or `rows` in `ROW_FIELDS` order."""
        self._check_loggable(topic)
        publish_ns = self._now_ns()
        strict = self._strict
        batch = self._batch
        count = len(batch)
        for log_time_ns, payload in messages:
            if type(log_time_ns) is not int:
                log_time_ns = operator.index(log_time_ns)  # numpy ints are fine, floats are not
            if isinstance(payload, tuple):
                if not rows:  # a tuple through `log`: its fields' order would be unchecked
                    raise TypeError(f"{topic}: a payload must be a mapping (rows go through log_columns)")
                if strict and not schemas.row_passes(topic, payload):  # a row field by field, by its name
                    schemas.check_payload(topic, schemas.row_payload(topic, payload))
            elif strict:
                schemas.check_payload(topic, payload)
            if not batch:
                self._batch_start_ns = log_time_ns
            batch.append((topic, log_time_ns, publish_ns, payload))
        added = len(batch) - count
        if added:
            self.messages_logged += added
            self._maybe_send(batch[-1][1])

    def _check_loggable(self, topic: str) -> None:
        if self._errors or self._fatal is not None:
            self._raise_errors()
        if self._finished:
            raise LogWriteError(f"{self.path}: log() after finish()")
        if topic not in schemas.TOPICS:
            raise KeyError(f"unknown topic {topic!r}; known: {', '.join(schemas.TOPICS)}")

    def _maybe_send(self, last_log_time_ns: int) -> None:
        """Send the batch once it is full or spans enough log time; back-pressure if far behind."""
        if (
            len(self._batch) >= self._batch_limit
            or last_log_time_ns - self._batch_start_ns >= BATCH_LOG_TIME_NS
        ):
            self._send_batch()
            if self._sent - self._written + self._batch_limit > self._max_pending:
                self._wait_for_drain()

    def flush(self, *, wait: bool = True, fsync: bool = False, timeout_s: float = 30.0) -> None:
        """Close the open chunk and flush the file; with `wait`, return once that is done.

        With `fsync` the data also reaches the disk (survives a power loss).
        """
        self._check_open("flush")
        token, done = self._new_request()
        self._send(("flush", token, fsync))
        if wait:
            self._wait(done, timeout_s, "flush")
        if self._errors or self._fatal is not None:
            self._raise_errors()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Add a metadata record (a str -> str map), written in order with the messages."""
        self._check_open("add_metadata")
        bad = [k for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise TypeError(f"metadata {name!r}: keys and values must be strings; bad keys: {bad}")
        self._send(("metadata", str(name), dict(data)))

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
        self._send(("attachment", args))

    def finish(self, timeout_s: float = 60.0) -> None:
        """Write everything queued, the summary and the footer, and close the file. Idempotent.

        Raises the first writer-process error not yet reported.
        """
        with self._finish_lock:
            if not self._finished:
                self._finished = True
                try:
                    token, done = self._new_request()
                    self._send(("finish", token))
                    self._wait(done, timeout_s, "finish")
                finally:
                    self._close_pipes(timeout_s)
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
        """Messages logged but not yet handled by the writer process."""
        return len(self._batch) + self._sent - self._written

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

    def _new_request(self) -> tuple[int, threading.Event]:
        token = next(self._tokens)
        done = self._done[token] = threading.Event()
        if self._fatal is not None or not self._reader.is_alive():
            done.set()  # nobody will answer
        return token, done

    def _send_batch(self) -> None:
        """Send the pending batch (caller holds no lock; `_send` serializes pipe writes)."""
        if self._batch:
            batch, self._batch = self._batch, []
            self._send(("batch", batch), count=len(batch))

    def _send(self, request: tuple[Any, ...], *, count: int = 0) -> None:
        """Send any pending batch, then `request`; a dead writer process becomes the fatal error."""
        with self._send_lock:
            if request[0] != "batch" and self._batch:
                batch, self._batch = self._batch, []
                self._write_request(("batch", batch), len(batch))
            self._write_request(request, count)

    def _write_request(self, request: tuple[Any, ...], count: int) -> None:
        if self._fatal is not None:
            if request[0] in ("flush", "finish"):
                self._release(request[1])
            return
        data = pickle.dumps(request, protocol=pickle.HIGHEST_PROTOCOL)
        self._sent += count
        try:
            self._requests.send_bytes(data)
        except OSError as error:  # the writer process is gone
            self._set_fatal(LogWriteError(f"the writer process ended ({error})"))

    def _wait(self, done: threading.Event, timeout_s: float, what: str) -> None:
        if not done.wait(timeout_s):
            raise RigTimeoutError(
                f"{self.path}: {what} not done after {timeout_s:g} s ({self.pending} queued)"
            )

    def _wait_for_drain(self) -> None:
        low_water = self._max_pending // 2
        with self._progress:
            self._progress.wait_for(
                lambda: self._sent - self._written <= low_water or self._fatal is not None, timeout=60.0
            )

    def _close_pipes(self, timeout_s: float) -> None:
        with contextlib.suppress(OSError):
            self._requests.close()  # end of file: the writer process stops if it has not yet
        try:
            self._process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait(timeout_s)
        self._reader.join(timeout_s)
        with contextlib.suppress(OSError):
            self._replies.close()

    # -- reader thread -----------------------------------------------------------------------

    def _read_replies(self) -> None:
        """Account for written messages, collect errors, and answer waiters until the pipe ends."""
        replies = self._replies
        while True:
            try:
                reply = pickle.loads(replies.recv_bytes())
            except (EOFError, OSError):
                break
            except Exception as error:  # pragma: no cover - a reply that does not unpickle
                self._set_fatal(error)
                break
            kind = reply[0]
            if kind == "written":
                with self._progress:
                    self._written += reply[1]
                    self._progress.notify_all()
            elif kind == "done":
                self._release(reply[1])
            elif kind == "error":
                self._errors.append(LogWriteError(reply[1]))
            elif kind == "fatal":
                self._set_fatal(reply[1])
        if not self._finished or self._done:
            code = self._process.poll()
            self._set_fatal(LogWriteError(f"the writer process ended unexpectedly (exit status {code})"))

    def _set_fatal(self, error: BaseException) -> None:
        with self._progress:
            if self._fatal is None:
                self._fatal = error
            self._progress.notify_all()
        for token in list(self._done):
            self._release(token)

    def _release(self, token: int) -> None:
        done = self._done.pop(token, None)
        if done is not None:
            done.set()
