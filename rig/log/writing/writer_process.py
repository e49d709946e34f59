"""The run logger's writer process: JSON encoding, MCAP chunking, compression and file I/O.

`RunLogger` (rig.log.writing.writer) starts this module as a child process (`python -m
rig.log.writing.writer_process ...`) so that the encoding work does not share the acquisition loop's GIL.
It reads pickled requests from one pipe and answers on another.

Requests (parent -> child), and the replies (child -> parent) they get:

* ``("topics", [(topic, schema_name, schema_bytes), ...], {topic: row_fields})``, always first
  (`rig.log.format.schemas.topics_request`): the schemas to register, and the topics whose
  payloads may come as rows; no reply. The child never imports the schemas module: building the
  schemas imports the records they describe, which would cost a third of a second per run.
* ``("batch", [(topic, log_ns, publish_ns, payload), ...])`` -> ``("written", n)`` once written
* ``("flush", token, fsync)`` -> ``("done", token)``
* ``("metadata", name, data)``, ``("attachment", args)`` -> no reply
* ``("finish", token)`` -> ``("done", token)``, then the process exits

Unprompted replies: ``("error", text)``, one message not written (a payload JSON cannot encode);
``("fatal", exception)``, the file cannot be trusted any more and nothing else is written.

The open chunk is closed (flushed) about every second of log time or wall time and whenever the
parent asks. If the parent dies (end of file on the request pipe) the process exits without
flushing the open chunk or writing a footer, exactly as if the writing had died with the parent:
the file keeps every flushed chunk and reads as unfinished. SIGINT and SIGTERM are ignored (the
parent decides when the file ends).
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import resource
import signal
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, BinaryIO

from mcap.writer import CompressionType, Writer

from rig.log.format.encoding import MESSAGE_ENCODING, SCHEMA_ENCODING, row_encoder
from rig.log.format.log_format import METADATA_NAME, format_metadata

COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


class _ParentGone(Exception):
    """The request pipe reached end of file: the parent process ended."""


class WriterProcess:
    """Serve one MCAP file: everything the parent sends is written in order.

    :param requests: the pipe the parent writes requests to.
    :param replies: the pipe this process answers on.
    :param stream: the file, already created by the parent; the MCAP header is written here.
    :param library: the MCAP header's library string.
    :param chunk_size: uncompressed bytes at which a chunk is closed.
    :param compression: "zstd", "lz4" or "none".
    :param flush_interval_ns: close the open chunk after this much log time or wall time.
    """

    def __init__(
        self,
        requests: Connection,
        replies: Connection,
        stream: BinaryIO,
        *,
        library: str,
        chunk_size: int,
        compression: str,
        flush_interval_ns: int,
    ) -> None:
        self._requests = requests
        self._replies = replies
        self._file = stream
        self._writer = Writer(stream, chunk_size=chunk_size, compression=COMPRESSION[compression])
        self._writer.start(profile="", library=library)
        self._writer.add_metadata(METADATA_NAME, format_metadata())
        self._file.flush()
        self._interval_ns = flush_interval_ns
        self._schemas: dict[str, tuple[str, bytes]] = {}  # topic -> (schema name, schema), from "topics"
        self._row_encoders: dict[str, Callable[[tuple[Any, ...]], bytes]] = {}
        self._channels: dict[str, int] = {}
        self._sequences: dict[int, int] = {}
        self._last_flush_log_ns: int | None = None
        self._last_flush_wall_ns = time.monotonic_ns()
        self._unflushed = False

    def _reply(self, message: tuple[Any, ...]) -> None:
        self._replies.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))

    def _receive(self) -> tuple[Any, ...]:
        if self._unflushed:
            timeout_s = max(0.0, (self._last_flush_wall_ns + self._interval_ns - time.monotonic_ns()) / 1e9)
            if not self._requests.poll(timeout_s):
                self._flush(fsync=False)
        try:
            data = self._requests.recv_bytes()
        except EOFError:
            raise _ParentGone from None
        request: tuple[Any, ...] = pickle.loads(data)
        return request

    def serve(self) -> None:
        """Write until the parent asks to finish (file finished) or goes away (file left unfinished)."""
        try:
            while True:
                request = self._receive()
                op = request[0]
                if op == "batch":
                    self._write_batch(request[1])
                elif op == "topics":
                    self._schemas = {topic: (name, schema) for topic, name, schema in request[1]}
                    self._row_encoders = {
                        topic: row_encoder(row, _DUMPS) for topic, row in request[2].items()
                    }
                elif op == "flush":
                    self._flush(fsync=request[2])
                    self._reply(("done", request[1]))
                elif op == "metadata":
                    self._writer.add_metadata(request[1], request[2])
                elif op == "attachment":
                    self._writer.add_attachment(*request[1])
                elif op == "finish":
                    try:
                        self._writer.finish()  # type: ignore[no-untyped-call]  # mcap: unannotated
                        self._file.flush()
                        os.fsync(self._file.fileno())
                    finally:
                        self._file.close()
                    self._reply(("done", request[1]))
                    return
                else:  # pragma: no cover - the parent only sends the ops above
                    raise ValueError(f"unknown request {op!r}")
        except _ParentGone:
            return
        except BaseException as error:  # the file cannot be trusted any more: stop writing
            self._report_fatal(error)
            self._drain_after_fatal()

    def _write_batch(self, batch: list[tuple[str, int, int, Any]]) -> None:
        dumps = _DUMPS
        row_encoders = self._row_encoders
        writer = self._writer
        channels = self._channels
        sequences = self._sequences
        interval_ns = self._interval_ns
        for topic, log_ns, publish_ns, payload in batch:
            channel_id = channels.get(topic)
            if channel_id is None:
                channel_id = self._register(topic)
            try:
                # A tuple is a row: the values of its topic's row fields, in order.
                data = row_encoders[topic](payload) if type(payload) is tuple else dumps(payload).encode()
            except (ValueError, TypeError, OverflowError) as error:
                self._reply(("error", f"{topic} message at log time {log_ns} not written: {error}"))
                continue
            sequence = sequences[channel_id] = (sequences[channel_id] + 1) & 0xFFFFFFFF
            writer.add_message(channel_id, log_ns, data, publish_ns, sequence)
            self._unflushed = True
            if self._last_flush_log_ns is None:
                self._last_flush_log_ns = log_ns
            if log_ns - self._last_flush_log_ns >= interval_ns:
                self._flush(fsync=False)
                self._last_flush_log_ns = log_ns
        if self._unflushed and time.monotonic_ns() - self._last_flush_wall_ns >= interval_ns:
            self._flush(fsync=False)
        self._reply(("written", len(batch)))

    def _register(self, topic: str) -> int:
        schema_name, schema = self._schemas[topic]
        schema_id = self._writer.register_schema(schema_name, SCHEMA_ENCODING, schema)
        channel_id = self._writer.register_channel(topic, MESSAGE_ENCODING, schema_id)
        self._channels[topic] = channel_id
        self._sequences[channel_id] = 0
        return channel_id

    def _flush(self, *, fsync: bool) -> None:
        self._writer.flush()  # type: ignore[no-untyped-call]  # mcap: unannotated
        if fsync:
            os.fsync(self._file.fileno())
        self._unflushed = False
        self._last_flush_wall_ns = time.monotonic_ns()

    def _report_fatal(self, error: BaseException) -> None:
        try:
            self._reply(("fatal", error))
        except Exception:  # unpicklable exception or pipe gone: say what it was
            with contextlib.suppress(Exception):  # the parent is gone; nothing left to tell
                self._reply(("fatal", RuntimeError(repr(error))))

    def _drain_after_fatal(self) -> None:
        """Close the file (unfinished); acknowledge every request until finish or the parent ends."""
        with contextlib.suppress(Exception):  # the fatal error is what gets reported
            self._file.close()
        while True:
            try:
                request = pickle.loads(self._requests.recv_bytes())
            except (EOFError, OSError):
                return
            if request[0] == "batch":
                self._reply(("written", len(request[1])))
            elif request[0] in ("flush", "finish"):
                self._reply(("done", request[1]))
                if request[0] == "finish":
                    return


_DUMPS = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode


def main(argv: list[str]) -> int:
    """Entry point: REQUEST_FD REPLY_FD FILE_FD LIBRARY CHUNK_SIZE COMPRESSION FLUSH_INTERVAL_NS MAX_BYTES.

    MAX_BYTES 0 (or absent) means no limit but the disk's.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    request_fd, reply_fd, file_fd = (int(a) for a in argv[:3])
    library, chunk_size, compression, interval_ns = argv[3], int(argv[4]), argv[5], int(argv[6])
    max_file_bytes = int(argv[7]) if len(argv) > 7 else 0
    if max_file_bytes > 0:
        # The operating system's own file-size limit: a write beyond it fails (EFBIG) as one on a
        # full disk does, instead of killing the process with SIGXFSZ.
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        hard = resource.getrlimit(resource.RLIMIT_FSIZE)[1]
        limit = max_file_bytes if hard == resource.RLIM_INFINITY else min(max_file_bytes, hard)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    requests = Connection(request_fd, writable=False)
    replies = Connection(reply_fd, readable=False)
    stream = os.fdopen(file_fd, "wb")
    try:
        process = WriterProcess(
            requests,
            replies,
            stream,
            library=library,
            chunk_size=chunk_size,
            compression=compression,
            flush_interval_ns=interval_ns,
        )
    except BaseException as error:
        stream.close()
        _report_startup_failure(replies, error)
        return 1
    process.serve()
    return 0


def _report_startup_failure(replies: Connection, error: BaseException) -> None:
    with contextlib.suppress(Exception):  # the parent is gone
        replies.send_bytes(pickle.dumps(("fatal", RuntimeError(repr(error)))))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
