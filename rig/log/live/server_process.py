"""The live view's server process: the Foxglove WebSocket server (`foxglove-sdk`) and the JSON encoding.

`LivePublisher` (rig.log.live.publisher) starts this module as a child process (`python -m
rig.log.live.server_process ...`), so that neither encoding nor handing messages to the server shares the
acquisition loop's GIL: the run's process only copies the batches it already pickled for the MCAP
writer into a pipe (`rig.log.writing.writer`). It imports nothing of the rig but this module, so that it
starts quickly. Frames on the data pipe (parent -> child) are an 8-byte little-endian length and a
pickled tuple; the first is always

* ``("topics", [(topic, schema_name, schema_bytes), ...], {topic: row_fields})``: the channels to
  advertise (`rig.log.format.schemas.TOPICS`) and the topics whose payloads may be rows

and then any of

* ``("batch", [(topic, log_ns, publish_ns, payload), ...])``: the logger's batch, as sent to the
  MCAP writer; messages of topics nobody subscribed to are skipped, the others encoded and published
* ``("encoded", [(topic, log_ns, data), ...])``: messages already encoded (replay of a file)
* ``("time", ns)``: tell clients the current log time (playback)
* ``("close",)``: publish what came before, stop the server (bounded), answer, exit

Replies (child -> parent, `Connection` messages): ``("ready", port)`` or ``("error", text)`` at
start; ``("subscribed", [topic, ...])`` whenever the set of subscribed topics changes;
``("stats", published, dropped, skipped, overflow_reports)`` now and then and ``("closed", ...)``
with the same counts at the end. End of file on the data pipe (the parent died) stops the server
and exits without a reply.

What the server itself loses is not countable: foxglove-sdk drops a slow client's oldest messages
when its per-client queue (`message_backlog_size`) is full and only logs "outbox for client ...
full", at most once per 30 s for the whole process, without the number of messages lost; the
reports are what `overflow_reports` counts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import pickle
import select
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import foxglove

from rig.log.format.encoding import MESSAGE_ENCODING, SCHEMA_ENCODING, row_encoder

FRAME_HEADER = struct.Struct("<Q")
POLL_INTERVAL_S = 0.02  # subscription checks and pipe reads: little latency, few wake-ups
STATS_INTERVAL_S = 0.25
# The server sends from its own tasks: messages handed to it just before `stop` may still be queued
# for a client when the connection closes, so the last ones are given this long to go out first.
FLUSH_GRACE_S = 0.3
_SERVER_LOGGER = "foxglove"


def _json_default(value: Any) -> Any:
    """Numpy scalars (and anything else with `item()`) as plain numbers."""
    item = getattr(value, "item", None)
    if item is None:
        raise TypeError(f"not JSON serializable: {type(value).__name__}")
    return item()


_DUMPS = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_json_default).encode


class _OverflowReports(logging.Handler):
    """Counts the server's 'outbox ... full' log lines (a client too slow; its oldest messages lost)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        if "full" in record.getMessage():
            self.count += 1


class LiveServer:
    """The server and its channels (one per rig topic), fed from the data pipe."""

    def __init__(
        self,
        context: Any,
        server: Any,
        channels: dict[str, Any],
        row_encoders: dict[str, Callable[[tuple[Any, ...]], bytes]],
        overflows: _OverflowReports,
    ) -> None:
        self._context = context  # the channels' context: they are advertised only while it lives
        self._server = server
        self._channels = channels
        self._row_encoders = row_encoders
        self._overflows = overflows
        self.published = 0
        self.dropped = 0  # could not be encoded as JSON
        self.skipped = 0  # nobody subscribed to the topic

    def counts(self) -> tuple[int, int, int, int]:
        """(published, dropped, skipped, overflow_reports)."""
        return self.published, self.dropped, self.skipped, self._overflows.count

    def subscribed(self) -> list[str]:
        """The topics a client subscribes to now."""
        return [topic for topic, channel in self._channels.items() if channel.has_sinks()]

    def handle(self, request: tuple[Any, ...]) -> bool:
        """Publish one frame's messages; False for `close`."""
        op = request[0]
        if op == "batch":
            self._publish_batch(request[1])
        elif op == "encoded":
            for topic, log_ns, data in request[1]:
                self._channels[topic].log(data, log_time=log_ns)
                self.published += 1
        elif op == "time":
            self._server.broadcast_time(request[1])
        elif op == "close":
            return False
        else:  # pragma: no cover - the parent only sends the ops above
            raise ValueError(f"unknown request {op!r}")
        return True

    def _publish_batch(self, batch: list[tuple[str, int, int, Any]]) -> None:
        channels, row_encoders = self._channels, self._row_encoders
        wanted: dict[str, bool] = {}
        for topic, log_ns, _publish_ns, payload in batch:
            want = wanted.get(topic)
            if want is None:
                want = wanted[topic] = channels[topic].has_sinks()
            if not want:
                self.skipped += 1
                continue
            try:
                data = row_encoders[topic](payload) if type(payload) is tuple else _DUMPS(payload).encode()
            except (TypeError, ValueError, KeyError):  # the MCAP writer reports it; the view skips it
                self.dropped += 1
                continue
            channels[topic].log(data, log_time=log_ns)
            self.published += 1

    def stop(self, timeout_s: float) -> None:
        """Stop the server, giving clients at most `timeout_s` to take their close frames."""
        # stop() waits for every client to take its close frame: a stalled client would hold it
        # (and this process) forever, so it is given `timeout_s` and then left behind.
        if self.published:
            time.sleep(min(FLUSH_GRACE_S, timeout_s))
        stopper = threading.Thread(target=self._server.stop, name="rig-live-stop", daemon=True)
        stopper.start()
        stopper.join(timeout_s)
        for channel in self._channels.values():
            channel.close()


def _start(
    topics: list[tuple[str, str, bytes]],
    row_fields: dict[str, tuple[str, ...]],
    *,
    host: str,
    port: int,
    name: str,
    backlog: int,
    playback: bool,
) -> tuple[LiveServer, int]:
    overflows = _OverflowReports()
    server_logger = logging.getLogger(_SERVER_LOGGER)
    server_logger.addHandler(overflows)
    server_logger.propagate = False  # the server's connection chatter stays off the console
    server_logger.setLevel(logging.INFO)
    context = foxglove.Context()
    server = foxglove.start_server(
        name=name,
        host=host,
        port=port,
        context=context,
        message_backlog_size=backlog,
        capabilities=[foxglove.Capability.Time] if playback else None,
    )
    channels = {
        topic: foxglove.Channel(
            topic,
            schema=foxglove.Schema(name=schema_name, encoding=SCHEMA_ENCODING, data=schema),
            message_encoding=MESSAGE_ENCODING,
            context=context,
        )
        for topic, schema_name, schema in topics
    }
    encoders = {topic: row_encoder(fields, _DUMPS) for topic, fields in row_fields.items()}
    return LiveServer(context, server, channels, encoders, overflows), int(server.port)


class _Frames:
    """Frames from the data pipe: `read(timeout_s)` returns those complete, None at end of file."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._buffer = bytearray()

    def read(self, timeout_s: float | None) -> list[tuple[Any, ...]] | None:
        readable, _, _ = select.select([self._fd], [], [], timeout_s)
        if not readable:
            return []
        chunk = os.read(self._fd, 1 << 20)
        if not chunk:
            return None
        buffer = self._buffer
        buffer += chunk
        frames = []
        start = 0
        while len(buffer) - start >= FRAME_HEADER.size:
            (size,) = FRAME_HEADER.unpack_from(buffer, start)
            end = start + FRAME_HEADER.size + size
            if len(buffer) < end:
                break
            frames.append(pickle.loads(memoryview(buffer)[start + FRAME_HEADER.size : end]))
            start = end
        del buffer[:start]
        return frames


def serve(frames: _Frames, replies: Connection, live: LiveServer, stop_timeout_s: float) -> None:
    """Publish frames until `close` (answered) or end of file (the parent is gone)."""
    subscribed: list[str] = []
    last_counts = live.counts()
    last_stats = time.monotonic()
    closing = False
    while not closing:
        received = frames.read(POLL_INTERVAL_S)
        if received is None:  # the parent is gone
            live.stop(stop_timeout_s)
            return
        for request in received:
            if not live.handle(request):
                closing = True
                break
        now_subscribed = live.subscribed()
        if now_subscribed != subscribed:
            subscribed = now_subscribed
            replies.send(("subscribed", subscribed))
        now = time.monotonic()
        if now - last_stats >= STATS_INTERVAL_S and live.counts() != last_counts:
            last_counts, last_stats = live.counts(), now
            replies.send(("stats", *last_counts))
    live.stop(stop_timeout_s)
    replies.send(("closed", *live.counts()))


def main(argv: list[str]) -> int:
    """Entry point: DATA_FD REPLY_FD HOST PORT NAME BACKLOG PLAYBACK STOP_TIMEOUT_S."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when the view ends
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    data_fd, reply_fd = int(argv[0]), int(argv[1])
    host, port, name = argv[2], int(argv[3]), argv[4]
    backlog, playback, stop_timeout_s = int(argv[5]), argv[6] == "1", float(argv[7])
    replies = Connection(reply_fd, readable=False)
    frames = _Frames(data_fd)
    pending: list[tuple[Any, ...]] = []
    while not pending:  # the first frame names the topics
        received = frames.read(None)
        if received is None:
            return 0
        pending = received
    _op, topics, row_fields = pending.pop(0)
    try:
        live, bound = _start(
            topics, row_fields, host=host, port=port, name=name, backlog=backlog, playback=playback
        )
    except Exception as error:  # the port (taken meanwhile), or foxglove-sdk could not start
        replies.send(("error", str(error) or repr(error)))
        return 1
    replies.send(("ready", bound))
    try:
        if all(live.handle(request) for request in pending):
            serve(frames, replies, live, stop_timeout_s)
        else:  # closed before it started
            live.stop(stop_timeout_s)
            replies.send(("closed", *live.counts()))
    except (BrokenPipeError, ConnectionResetError):  # the parent is gone
        with contextlib.suppress(Exception):
            live.stop(stop_timeout_s)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
