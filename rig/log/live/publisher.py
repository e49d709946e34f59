"""Live view: the run's topics served over the Foxglove WebSocket protocol (`foxglove-sdk`).

`LivePublisher` starts the server in a child process (`rig.log.live.server_process`) that advertises every
topic of `rig.log.format.schemas.TOPICS` (the same schema names and JSON Schemas as the MCAP file). The
run's live sink (`rig.runner.sinks.LiveSink`) hands it batches pickled as the MCAP writer's are
(`publish_pickled`), one pipe write per batch and only while some client subscribes to something:
the JSON encoding, the subscription checks and the hand-over to the server all happen in the child,
so the acquisition loop neither encodes twice nor shares its GIL with the view. Nothing waits for a
client or for the child: a batch that does not fit in the pipe is dropped and counted (`dropped`),
and the server drops a slow client's oldest messages (reported, not counted: see `LiveStats`).

`serve_log` plays recorded MCAP files to the same server (`rig replay --serve`).
"""

from __future__ import annotations

import contextlib
import errno
import heapq
import math
import operator
import os
import pickle
import select
import socket
import struct
import subprocess
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader

from rig.errors import InputError
from rig.log.child_process import start_child
from rig.log.format import schemas

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
CLIENT_BACKLOG = 4096  # messages the server buffers per client before dropping its oldest
PIPE_BYTES = 1 << 20  # data pipe capacity (about 25,000 load-cell rows) before batches are dropped
START_TIMEOUT_S = 30.0
_FRAME_HEADER = struct.Struct("<Q")  # as rig.log.live.server_process.FRAME_HEADER

Message = tuple[int, Mapping[str, Any] | tuple[Any, ...]]


@dataclass(frozen=True)
class LiveStats:
    """What the live view published and lost.

    `dropped` counts messages: those that did not fit in the pipe to the server process (it fell
    behind) or could not be encoded as JSON. `slow_client_events` counts foxglove-sdk's reports
    that a client's outbox was full: the server then drops that client's oldest messages, but the
    SDK exposes no count of them (it logs "outbox for client ... full" at most once per 30 s for
    the whole process), so a report means "a client lost messages", not how many.
    """

    published: int
    dropped: int
    slow_client_events: int
    failure: str | None = None  # the server could not serve (e.g. its port was taken meanwhile)

    def text(self) -> str:
        """One line for the run's log."""
        if self.failure is not None:
            return f"live view: not served ({self.failure})"
        return (
            f"live view: {self.published} messages published, "
            f"{self.dropped} dropped (server process behind, or not JSON); "
            f"{self.slow_client_events} slow-client reports (foxglove-sdk: a client's outbox was full "
            "and lost its oldest messages; it reports at most once per 30 s and not how many)"
        )


def _free_port(host: str, port: int) -> int:
    """`port` if it can be bound on `host` now (a free one for 0); InputError naming it otherwise."""
    try:
        family, kind, _proto, _name, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server binds
            probe.bind(address)
            bound: int = probe.getsockname()[1]
    except OSError as error:
        raise InputError(
            f"--live-port {port}: cannot serve on {host}:{port} ({error.strerror or error}); "
            "allowed: a free port (0 picks one)"
        ) from None
    return bound


class LivePublisher:
    """A Foxglove WebSocket server for the rig topics, in a child process; publishing never blocks.

    :param host: the address to bind (localhost by default).
    :param port: the TCP port; 0 picks a free one (see `port`).
    :param client_backlog: messages the server buffers per client before dropping its oldest.
    :param playback: a recorded log is served: clients are told its time (`broadcast_time`).
    :param pipe_bytes: the pipe to the server process; a batch that does not fit is dropped.
    :raises InputError: the port cannot be bound (in use, not allowed).
    """

    def __init__(
        self,
        *,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        name: str = "slip-trial rig",
        client_backlog: int = CLIENT_BACKLOG,
        playback: bool = False,
        pipe_bytes: int = PIPE_BYTES,
        stop_timeout_s: float = 2.0,
    ) -> None:
        port = _free_port(host, port)  # a port in use is an InputError now, before anything moves
        child = start_child(
            "rig.log.live.server_process",
            [host, str(port), name, str(client_backlog), "1" if playback else "0", str(stop_timeout_s)],
            pipe_bytes=pipe_bytes,
        )
        self._process = child.process
        data_write, reply_read = child.request_fd, child.reply_fd
        os.set_blocking(data_write, False)  # publishing never waits for the server process
        self.host = host
        self.port = port
        self._data = data_write
        self._replies = Connection(reply_read, writable=False)
        self._stop_timeout_s = stop_timeout_s
        self._lock = threading.Lock()  # one writer of frames at a time
        self._remainder = b""  # the unwritten end of a frame the pipe took only part of
        self._subscribed: frozenset[str] = frozenset()
        self._child_counts: tuple[int, ...] = (0, 0, 0, 0)  # published, dropped, skipped, reports
        self._sent = 0  # messages handed to the server process
        self._dropped = 0  # messages that did not fit in the pipe
        self._ready = threading.Event()  # the server listens (or failed: `failure`)
        self.failure: str | None = None  # why the server process could not serve
        self._closed_event = threading.Event()
        self._closed: LiveStats | None = None
        # The child starts (imports foxglove, binds) while this process goes on with the run.
        self._send(pickle.dumps(schemas.topics_request()), 0, wait_s=START_TIMEOUT_S)
        self._reader = threading.Thread(target=self._read_replies, name="rig-live-replies", daemon=True)
        self._reader.start()

    def wait_ready(self, timeout_s: float = START_TIMEOUT_S) -> bool:
        """Wait until the server listens; False if it failed (`failure`) or is not up in time."""
        return self._ready.wait(timeout_s) and self.failure is None

    @property
    def pid(self) -> int:
        """The server process's id."""
        return self._process.pid

    @property
    def url(self) -> str:
        """The WebSocket address to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    @property
    def has_subscribers(self) -> bool:
        """Whether a client is subscribed to any topic (while none is, what is published is skipped)."""
        return bool(self._subscribed) and self._closed is None

    def wants(self, topic: str) -> bool:
        """Whether a client is subscribed to `topic` (as the server process last reported)."""
        return topic in self._subscribed

    def publish_pickled(self, frame: bytes, count: int) -> None:
        """Hand over `count` messages pickled as `("batch", [(topic, log_ns, publish_ns, payload), ...])`.

        The form the MCAP writer's batches take. Skipped while no client
        subscribes to anything; dropped (and counted) if the pipe has no room.
        """
        if self._subscribed and self._closed is None:
            self._send(frame, count)

    def publish(self, topic: str, messages: Sequence[Message]) -> None:
        """Hand over `(log_time_ns, payload)` messages of one topic (a payload may be a row)."""
        if messages and self._subscribed and self._closed is None:
            batch = [(topic, t, t, payload) for t, payload in messages]
            self._send(pickle.dumps(("batch", batch), protocol=pickle.HIGHEST_PROTOCOL), len(messages))

    def publish_encoded(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Send an already-encoded JSON message (replay: the bytes as the file holds them); may wait."""
        frame = pickle.dumps(("encoded", [(topic, log_time_ns, data)]), protocol=pickle.HIGHEST_PROTOCOL)
        self._send(frame, 1, wait_s=self._stop_timeout_s)

    def broadcast_time(self, time_ns: int) -> None:
        """Tell clients the current (log) time, for playback of a recorded log."""
        self._send(pickle.dumps(("time", time_ns), protocol=pickle.HIGHEST_PROTOCOL), 0, wait_s=1.0)

    def _send(self, frame: bytes, count: int, *, wait_s: float = 0.0) -> bool:
        """Write one frame; count it sent (True) or dropped (False).

        Without `wait_s` it never waits: a frame the pipe takes only in part is sent (its rest goes
        first next time), one it has no room for is dropped. With `wait_s` it waits at most that
        long for the whole frame to be written.
        """
        data = _FRAME_HEADER.pack(len(frame)) + frame
        deadline = time.monotonic() + wait_s
        accepted = False
        with self._lock:
            while True:
                if self._remainder:
                    self._remainder = self._write_some(self._remainder)
                if not accepted and not self._remainder:
                    rest = self._write_some(data)
                    if len(rest) < len(data):
                        accepted, self._remainder = True, rest
                        self._sent += count
                if accepted and (wait_s <= 0 or not self._remainder):
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    if not accepted:
                        self._dropped += count
                    return accepted
                select.select([], [self._data], [], min(left, 0.05))

    def _write_some(self, data: bytes) -> bytes:
        """Write what the pipe takes now; the unwritten rest (all of it if nothing was written)."""
        try:
            n = os.write(self._data, data)
        except BlockingIOError:
            return data
        except OSError as error:  # the server process is gone: nothing more will be delivered
            if error.errno != errno.EPIPE:
                raise
            return data
        return data[n:]

    def stats(self) -> LiveStats:
        """The counts so far (the server process reports its part a few times a second)."""
        published, child_dropped, _skipped, reports = self._child_counts
        return LiveStats(published, self._dropped + child_dropped, reports, self.failure)

    def close(self, timeout_s: float = 2.0) -> LiveStats:
        """Publish what is handed over (for at most `timeout_s`), stop the server; idempotent."""
        if self._closed is not None:
            return self._closed
        closed = self.failure is None and self._send(pickle.dumps(("close",)), 0, wait_s=timeout_s)
        if not (closed and self._closed_event.wait(timeout_s + self._stop_timeout_s + 1.0)):
            # The server process is behind or stuck: what it has not accounted for is lost.
            self._process.kill()
            published, child_dropped, skipped, _reports = self._child_counts
            self._dropped += max(0, self._sent - published - child_dropped - skipped)
        self._closed = self.stats()
        self._shutdown()
        return self._closed

    def _shutdown(self) -> None:
        """Close the pipe (the server process stops at its end), wait for the process and the reader."""
        with contextlib.suppress(OSError):
            os.close(self._data)
        try:
            self._process.wait(self._stop_timeout_s + 5.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._reader.join(5.0)
        with contextlib.suppress(OSError):
            self._replies.close()

    def _read_replies(self) -> None:
        """Keep the subscriptions and counts the server process reports, until it ends."""
        while True:
            try:
                reply = self._replies.recv()
            except (EOFError, OSError):
                if not self._ready.is_set():
                    self.failure = f"the server process ended (exit status {self._process.wait()})"
                    self._ready.set()
                return
            kind = reply[0]
            if kind == "ready":
                self._ready.set()
            elif kind == "error":
                self.failure = f"cannot serve on {self.host}:{self.port}: {reply[1]}"
                self._ready.set()
            elif kind == "subscribed":
                self._subscribed = frozenset(reply[1])
            elif kind in ("stats", "closed"):
                self._child_counts = tuple(reply[1:5])
                if kind == "closed":
                    self._closed_event.set()

    def __enter__(self) -> LivePublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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
