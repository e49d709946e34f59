"""Live view: the run's topics served over the Foxglove WebSocket protocol (`foxglove-sdk`).

`LivePublisher` starts a server that advertises every topic of `rig.log.schemas.TOPICS` (the same
schema names and JSON Schemas as the MCAP file). `RunLogger` tees what it logs into `publish()`,
which costs the acquisition loop a subscription check and, for a subscribed topic, a deque append:
the JSON encoding and the hand-over to the server happen in a publisher thread, and the server
sends from its own (Rust) threads. Nothing waits for a client: when the publisher queue is full the
newest messages are dropped (`dropped`), and a client that reads too slowly loses its oldest
messages in the server (each such episode counted in `slow_client_events`).

`serve_log` plays recorded MCAP files to the same server (`rig replay --serve`).
"""

from __future__ import annotations

import collections
import heapq
import json
import logging
import math
import operator
import struct
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import foxglove
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader

from rig.errors import InputError
from rig.log import schemas

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
DEFAULT_MAX_QUEUED = 50_000  # messages waiting for the publisher thread (~50 s of load-cell rows)
DRAIN_INTERVAL_S = 0.02  # publisher thread period: few wake-ups (and GIL hand-overs), little latency
CLIENT_BACKLOG = 4096  # messages the server buffers per client before dropping its oldest
_SERVER_LOGGER = "foxglove"

Message = tuple[int, Mapping[str, Any] | tuple[Any, ...]]


def _row_encoder(fields: tuple[str, ...]) -> Callable[[tuple[Any, ...]], bytes]:
    """The JSON of a row: a %-template when every value is an int or a finite float.

    Ten times quicker than a dict through `json.dumps`, which encodes anything else (None).
    """
    template = ("{" + ",".join(f'"{name}":%r' for name in fields) + "}").encode()
    plain = (int, float)

    def encode(row: tuple[Any, ...]) -> bytes:
        if all(type(v) in plain and math.isfinite(v) for v in row):
            return template % row
        obj = dict(zip(fields, row, strict=True))
        return json.dumps(obj, separators=(",", ":"), default=_json_default).encode()

    return encode


def _json_default(value: Any) -> Any:
    """Numpy scalars (and anything else with `item()`) as plain numbers."""
    item = getattr(value, "item", None)
    if item is None:
        raise TypeError(f"not JSON serializable: {type(value).__name__}")
    return item()


_ROW_ENCODERS = {topic: _row_encoder(fields) for topic, fields in schemas.ROW_FIELDS.items()}


@dataclass(frozen=True)
class LiveStats:
    """What the live view published and lost."""

    published: int
    dropped: int  # the publisher queue was full
    slow_client_events: int  # a client's server-side outbox overflowed (its oldest messages lost)

    def text(self) -> str:
        """One line for the run's log."""
        return (
            f"live view: {self.published} messages published, "
            f"{self.dropped} dropped (queue full or not JSON), "
            f"{self.slow_client_events} slow-client overflows"
        )


class _OverflowCounter(logging.Handler):
    """Counts the server's 'outbox full' reports (a client too slow; messages dropped)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        if "full" in record.getMessage():
            self.count += 1


class LivePublisher:
    """A Foxglove WebSocket server for the rig topics; `publish` never blocks.

    :param host: the address to bind (localhost by default).
    :param port: the TCP port; 0 picks a free one (see `port`).
    :param max_queued: messages the publisher thread may lag behind before new ones are dropped.
    :param client_backlog: messages the server buffers per client before dropping its oldest.
    :param playback: a recorded log is served: clients are told its time (`broadcast_time`).
    :raises InputError: the port cannot be bound (in use, not allowed).
    """

    def __init__(
        self,
        *,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        name: str = "slip-trial rig",
        max_queued: int = DEFAULT_MAX_QUEUED,
        client_backlog: int = CLIENT_BACKLOG,
        playback: bool = False,
    ) -> None:
        self._overflows = _OverflowCounter()
        server_logger = logging.getLogger(_SERVER_LOGGER)
        server_logger.addHandler(self._overflows)
        server_logger.propagate = False  # the server's connection chatter stays off the console
        if server_logger.level == logging.NOTSET or server_logger.level > logging.INFO:
            server_logger.setLevel(logging.INFO)
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                context=self._context,
                message_backlog_size=client_backlog,
                capabilities=[foxglove.Capability.Time] if playback else None,
            )
        except RuntimeError as error:
            server_logger.removeHandler(self._overflows)
            raise InputError(
                f"--live-port {port}: cannot serve on {host}:{port} ({error}); "
                "allowed: a free port (0 picks one)"
            ) from None
        self.host = host
        self.port: int = self._server.port
        self._channels = {
            topic: foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=spec.schema_name, encoding="jsonschema", data=spec.schema_bytes),
                message_encoding=schemas.MESSAGE_ENCODING,
                context=self._context,
            )
            for topic, spec in schemas.TOPICS.items()
        }
        self._max_queued = max_queued
        self._queue: collections.deque[tuple[str, Sequence[Message]]] = collections.deque()
        self._queued = 0  # messages in _queue (approximate across threads; only bounds the queue)
        self._wake = threading.Event()
        self._stopping = False
        self._abandon = False
        self.published = 0
        self.dropped = 0
        self._closed: LiveStats | None = None
        self._thread = threading.Thread(target=self._run, name="rig-live", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """The WebSocket address to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def wants(self, topic: str) -> bool:
        """Whether a client is subscribed to `topic` (cheap: checked before building anything for it)."""
        channel = self._channels.get(topic)
        return channel is not None and channel.has_sinks()

    def publish(self, topic: str, messages: Sequence[Message]) -> None:
        """Queue `(log_time_ns, payload)` messages of one topic; drops them if the queue is full.

        A payload may be a row (`schemas.ROW_FIELDS`); it becomes an object in the publisher thread.
        The payloads must not be changed afterwards.
        """
        if not messages or self._stopping:
            return
        if self._queued + len(messages) > self._max_queued:
            self.dropped += len(messages)
            return
        self._queued += len(messages)
        self._queue.append((topic, messages))  # no wake-up: the thread drains every DRAIN_INTERVAL_S

    def publish_encoded(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Send an already-encoded JSON message now (replay: the bytes as the file holds them)."""
        channel = self._channels.get(topic)
        if channel is not None:
            channel.log(data, log_time=log_time_ns)
            self.published += 1

    def broadcast_time(self, time_ns: int) -> None:
        """Tell clients the current (log) time, for playback of a recorded log."""
        self._server.broadcast_time(time_ns)

    def stats(self) -> LiveStats:
        """The counts so far."""
        return LiveStats(self.published, self.dropped, self._overflows.count)

    def close(self, timeout_s: float = 2.0) -> LiveStats:
        """Publish what is queued (for at most `timeout_s`), stop the server; idempotent."""
        if self._closed is None:
            self._stopping = True
            self._wake.set()
            self._thread.join(timeout_s)
            if self._thread.is_alive():  # behind: what is still queued counts as dropped
                self._abandon = True
                self._thread.join(timeout_s)
                self.dropped += max(0, self._queued)
            # stop() waits for every client to take its close frame: a stalled client would hold it
            # (and this process) forever, so it is given `timeout_s` and then left behind.
            stopper = threading.Thread(target=self._server.stop, name="rig-live-stop", daemon=True)
            stopper.start()
            stopper.join(timeout_s)
            for channel in self._channels.values():
                channel.close()
            logging.getLogger(_SERVER_LOGGER).removeHandler(self._overflows)
            self._closed = self.stats()
        return self._closed

    def __enter__(self) -> LivePublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _run(self) -> None:
        """Publisher thread: encode queued messages and hand them to the server."""
        queue, channels = self._queue, self._channels
        while True:
            self._wake.wait(DRAIN_INTERVAL_S)
            self._wake.clear()
            while queue and not self._abandon:
                topic, messages = queue.popleft()
                self._queued -= len(messages)
                channel = channels[topic]
                if not channel.has_sinks():
                    continue  # the client unsubscribed meanwhile
                encode_row = _ROW_ENCODERS.get(topic)
                for log_time_ns, payload in messages:
                    try:
                        if type(payload) is tuple and encode_row is not None:
                            data = encode_row(payload)
                        else:
                            data = json.dumps(payload, separators=(",", ":"), default=_json_default).encode()
                    except (TypeError, ValueError):  # the file's writer reports it; the view skips it
                        self.dropped += 1
                        continue
                    channel.log(data, log_time=log_time_ns)
                    self.published += 1
            if self._stopping:
                return


def _file_messages(path: Path, warnings: list[str]) -> Iterator[tuple[int, str, bytes]]:
    """`(log_time_ns, topic, data)` of one file's rig topics, read as a stream (unfinished files too)."""
    try:
        with path.open("rb") as f:
            for _schema, channel, message in NonSeekingReader(f).iter_messages(log_time_order=True):
                if channel.topic in schemas.TOPICS:
                    yield message.log_time, channel.topic, message.data
    except (McapError, EOFError, ValueError, struct.error) as error:
        warnings.append(f"{path}: stopped at a damaged or missing record ({error})")


def serve_log(
    paths: Sequence[Path],
    live: LivePublisher,
    *,
    speed: float = 1.0,
    wait_for_client: Callable[[], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
    monotonic: Callable[[], float] = time.monotonic,
) -> tuple[int, list[str]]:
    """Publish the messages of MCAP files in log-time order, paced at `speed` times real time.

    The payloads are sent as the files hold them. `wait_for_client` is called first (e.g. to wait
    for a subscription). Returns the number of messages sent and the files' warnings.
    """
    if not speed > 0 or math.isinf(speed):
        raise ValueError(f"speed {speed}: must be a positive finite number")
    warnings: list[str] = []
    merged = heapq.merge(*(_file_messages(p, warnings) for p in paths), key=operator.itemgetter(0))
    if wait_for_client is not None:
        wait_for_client()
    first: int | None = None
    start = monotonic()
    sent = 0
    last_broadcast = -math.inf
    for log_time_ns, topic, data in merged:
        if first is None:
            first = log_time_ns
        due = start + (log_time_ns - first) / 1e9 / speed
        ahead = due - monotonic()
        if ahead > 0.001:
            sleep(ahead)
        live.publish_encoded(topic, log_time_ns, data)
        sent += 1
        if due - last_broadcast >= 0.1:
            live.broadcast_time(log_time_ns)
            last_broadcast = due
    return sent, warnings
