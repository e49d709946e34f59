"""Bounded scanning of one MCAP file (finished, crashed or damaged) into per-topic raw payloads.

A finished file (footer, summary and chunk indexes intact) is read through its index: each chunk
listed in the summary is read at its offset, and the counts are checked against the Statistics
record. Any other file (a crashed run with no footer, a truncated copy, a damaged summary) is read
in one linear pass over its records, which keeps every complete chunk and says in `warnings` what
was lost. Both paths decompress chunks themselves and check their CRC, so a corrupted chunk is
skipped with a warning and the others still come back. A linear pass that meets garbage (a damaged
record header) searches forward for the next valid chunk and reports the bytes it skipped.

Every allocation is bounded by the file, whatever its headers claim: a record is never read past
the end of the file (or of the record, chunk or summary that holds it), and a chunk is decompressed
only if it declares at most `MAX_CHUNK_UNCOMPRESSED_BYTES` and at most `MAX_COMPRESSION_RATIO` times
its compressed size, never into more than it declares. A record or chunk that breaks a bound is
skipped with a warning naming the file and its byte offset, and reading goes on with the rest.

(mcap 1.6.0's own readers were not enough here: `make_reader(...).iter_messages()` yields nothing
from an unfinished file, `StreamReader` stops at the first bad record,
`iter_messages(log_time_order=False)` decompresses the whole file before the first message, and
`SeekingReader` reads a record of whatever length it declares straight from the file. Only mcap's
record classes are used, on record bodies already read within bounds.)

`scan_file` fills a `FileScan`: messages per topic as raw payloads, decoded in column batches
(`rig.log.reading.frames`), with the file's metadata, attachments and what was lost. `rig.log.reading.reader`
makes a run's `RunLog` from the scans of its files.

A scan also notes where the messages it read are (`Span`: a chunk, or a run of top-level records,
with the log times of its messages), so that a time window of a topic can be read again later
(`scan_window`) without decoding, or keeping, the rest of the file: the high-rate topics of a long
run are read one trial at a time. A window is read from exactly the spans whose messages the scan
kept, with the same bounds and checks.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    Channel,
    ChunkIndex,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

from rig.errors import InputError
from rig.log.reading.frames import TopicBatches

try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover - mcap 1.6.0 requires lz4
    lz4_frame = None


MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEADER = struct.Struct("<BQ")  # opcode, content length
_MESSAGE_HEADER = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK_HEADER = struct.Struct("<QQQII")  # start, end, uncompressed size, uncompressed crc, compression length
_FOOTER_SIZE = 9 + 20 + len(MAGIC)  # record header, summary start, summary offset start, crc; magic
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
_SCAN_BLOCK = 1 << 22
_CHUNK_PROBE = 9 + 32 + 4 + 8  # record header, chunk header, longest compression name, records length
# A chunk is decompressed only within both bounds (the rig's chunks: at most 512 KiB, ratio 2-7).
MAX_CHUNK_UNCOMPRESSED_BYTES = 256 << 20
MAX_COMPRESSION_RATIO = 200
# What parsing a record body can raise (the body itself is always within bounds).
_RECORD_ERRORS = (McapError, EOFError, ValueError, struct.error, OverflowError)
# Consecutive top-level records (a file written without chunks) are noted as spans up to this size.
MAX_RECORDS_SPAN_BYTES = 1 << 20
# Log times are u64: a window that keeps every message.
ALL_TIMES = (0, (1 << 64) - 1)
_READ_IN_LINEAR_PASS = frozenset(
    int(op)
    for op in (
        Opcode.HEADER,
        Opcode.SCHEMA,
        Opcode.CHANNEL,
        Opcode.MESSAGE,
        Opcode.CHUNK,
        Opcode.METADATA,
        Opcode.ATTACHMENT,
    )
)


@dataclass(frozen=True)
class Attachment:
    """An attachment (e.g. the protocol file) and the log file it came from."""

    file: Path
    name: str
    media_type: str
    log_time_ns: int
    create_time_ns: int
    data: bytes


@dataclass(frozen=True)
class FileReport:
    """What reading one file found."""

    path: Path
    finished: bool  # footer and summary intact
    complete: bool  # finished and nothing damaged
    library: str
    messages: int
    chunks: int  # chunks whose messages were recovered
    chunks_skipped: int
    first_log_time_ns: int | None
    warnings: tuple[str, ...]


class _Fields:
    """Little-endian fields of one record body, read in order; nothing is read past its end."""

    __slots__ = ("data", "pos")

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def u32(self) -> int:
        (value,) = struct.unpack_from("<I", self.data, self.pos)
        self.pos += 4
        return int(value)

    def u64(self) -> int:
        (value,) = struct.unpack_from("<Q", self.data, self.pos)
        self.pos += 8
        return int(value)

    def take(self, length: int, what: str) -> bytes:
        left = len(self.data) - self.pos
        if length > left:
            raise ValueError(f"{what} declares {length} bytes, {left} left in the record")
        self.pos += length
        return self.data[self.pos - length : self.pos]

    def text(self, what: str) -> str:
        return self.take(self.u32(), what).decode()


@dataclass
class _Channel:
    topic: str
    message_encoding: str
    schema_name: str


@dataclass(slots=True)
class Span:
    """Where some of a file's messages are, to read them again: one chunk, or a run of top-level records."""

    offset: int  # byte offset of the Chunk record, or of the first of the records
    length: int  # bytes from `offset`: the whole Chunk record, or the run of records
    chunk: bool
    first_log_time_ns: int  # earliest and latest log time of the messages in it
    last_log_time_ns: int
    channels_known: int  # how many channels the scan knew before reading it (first of `FileScan.channels`)

    def overlaps(self, first_ns: int, last_ns: int) -> bool:
        """Whether a message of this span may have a log time from `first_ns` to `last_ns`."""
        return self.first_log_time_ns <= last_ns and self.last_log_time_ns >= first_ns


@dataclass(frozen=True)
class SpanSource:
    """What reading a time window of one file again needs: its channels and spans, as first scanned."""

    path: Path
    size: int  # the file's size when scanned: nothing after it is read
    channels: tuple[tuple[int, _Channel], ...]  # in the order the scan met them
    spans: tuple[Span, ...]  # in file order


@dataclass
class FileScan:
    """The state of reading one file; messages go to the run-wide per-topic batches.

    Messages whose log time is outside `window` (inclusive) are counted but not kept.
    """

    path: Path
    size: int
    batches: dict[str, TopicBatches]
    wanted: frozenset[str] | None
    batch_size: int
    label: str = ""
    finished: bool = False
    damaged: bool = False
    library: str = ""
    schemas: dict[int, str] = field(default_factory=dict)
    channels: dict[int, _Channel] = field(default_factory=dict)
    sinks: dict[int, TopicBatches | None] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)  # per channel id, 0 = unknown channel
    first_log_time_ns: int | None = None
    chunks: int = 0
    chunks_skipped: int = 0
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: list[Attachment] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    window: tuple[int, int] = ALL_TIMES
    deferred: frozenset[str] = frozenset()  # wanted topics only located (spans), read later by window
    spans: list[Span] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.label = self.path.name

    def warn(self, text: str, *, damage: bool = True) -> None:
        self.warnings.append(f"{self.label}: {text}")
        self.damaged = self.damaged or damage

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    # -- records -----------------------------------------------------------------------------

    def add_schema(self, schema: Schema) -> None:
        self.schemas[schema.id] = schema.name

    def add_channel(self, channel: Channel) -> None:
        if channel.id in self.channels:
            return
        schema_name = self.schemas.get(channel.schema_id, "")
        self.known_channel(channel.id, _Channel(channel.topic, channel.message_encoding, schema_name))

    def known_channel(self, channel_id: int, channel: _Channel) -> None:
        """Register a channel (one this scan or an earlier scan of the file read); the first one counts."""
        if channel_id in self.channels:
            return
        self.channels[channel_id] = channel
        sink = None
        if self.wanted is None or channel.topic in self.wanted:
            if channel.topic in self.deferred:
                pass
            elif channel.message_encoding == "json":
                sink = self.batches.get(channel.topic)
                if sink is None:
                    sink = self.batches[channel.topic] = TopicBatches(channel.topic, self.batch_size)
            else:
                self.warn(
                    f"{channel.topic}: encoding {channel.message_encoding!r} is not JSON; not decoded",
                    damage=False,
                )
        self.sinks[channel_id] = sink
        self.counts.setdefault(channel_id, 0)

    def add_records(self, data: bytes, where: str) -> tuple[int, int] | None:
        """Parse the records of a chunk (or a run of top-level records); messages go to the batches.

        Returns the earliest and latest log time of the messages parsed (None without messages).
        """
        sinks = self.sinks
        counts = self.counts
        unpack_record = _RECORD_HEADER.unpack_from
        unpack_message = _MESSAGE_HEADER.unpack_from
        keep_from, keep_to = self.window
        first_time = last_time = -1
        pending = {id(sink): len(sink.payloads) for sink in self.batches.values()}
        size = len(data)
        unreadable = 0
        pos = 0
        while pos + 9 <= size:
            opcode, length = unpack_record(data, pos)
            body = pos + 9
            end = body + length
            if end > size:
                break
            if opcode == 5:  # Message
                if length < 22:
                    unreadable += 1
                    pos = end
                    continue
                channel_id, _sequence, log_time, publish_time = unpack_message(data, body)
                sink = sinks.get(channel_id)
                if sink is not None and keep_from <= log_time <= keep_to:
                    sink.payloads.append(data[body + 22 : end])
                    sink.log_times.append(log_time)
                    sink.publish_times.append(publish_time)
                if channel_id in counts:
                    counts[channel_id] += 1
                else:
                    counts[0] = counts.get(0, 0) + 1
                if log_time < first_time or first_time < 0:
                    first_time = log_time
                if log_time > last_time:
                    last_time = log_time
            elif opcode == Opcode.SCHEMA or opcode == Opcode.CHANNEL:
                try:
                    if opcode == Opcode.SCHEMA:
                        self.add_schema(Schema.read(_stream(data[body:end])))
                    else:
                        self.add_channel(Channel.read(_stream(data[body:end])))
                except _RECORD_ERRORS:
                    unreadable += 1
            pos = end
        if first_time >= 0 and (self.first_log_time_ns is None or first_time < self.first_log_time_ns):
            self.first_log_time_ns = first_time
        if unreadable:
            self.warn(f"{where}: {unreadable} unreadable records (damaged); skipped")
        if pos != size:
            self.warn(f"{where}: records end {size - pos} bytes early (damaged); kept what came before")
        for sink in self.batches.values():
            if len(sink.payloads) != pending.get(id(sink), 0):
                sink.pending_bytes += size  # at most this much of `data` went to the sink
            if len(sink.payloads) >= sink.batch_size or sink.pending_bytes >= sink.max_pending_bytes:
                sink.decode_pending()
        return (first_time, last_time) if last_time >= 0 else None

    def add_span(self, offset: int, length: int, chunk: bool, times: tuple[int, int], known: int) -> None:
        """Note where messages were read (runs of top-level records merged up to a bound)."""
        last = self.spans[-1] if self.spans else None
        if (
            not chunk
            and last is not None
            and not last.chunk
            and last.offset + last.length == offset
            and last.length + length <= MAX_RECORDS_SPAN_BYTES
        ):
            last.length += length
            last.first_log_time_ns = min(last.first_log_time_ns, times[0])
            last.last_log_time_ns = max(last.last_log_time_ns, times[1])
            return
        self.spans.append(Span(offset, length, chunk, times[0], times[1], known))

    def source(self) -> SpanSource:
        """What `scan_window` needs to read a time window of this file again."""
        return SpanSource(self.path, self.size, tuple(self.channels.items()), tuple(self.spans))

    def add_chunk(self, body: bytes, offset: int) -> None:
        """Decompress one Chunk record's content within bounds, check its CRC and parse its records."""
        where = f"chunk at byte {offset}"
        try:
            _start, _end, uncompressed_size, crc, name_length = _CHUNK_HEADER.unpack_from(body, 0)
            compression = bytes(body[32 : 32 + name_length]).decode()
            (records_length,) = struct.unpack_from("<Q", body, 32 + name_length)
            records_start = 40 + name_length
            if records_start + records_length > len(body):
                raise ValueError("records run past the end of the chunk")
        except (struct.error, ValueError) as error:
            self.skip_chunk(f"{where}: unreadable chunk header ({_short(error)}); skipped")
            return
        problem = _chunk_size_problem(compression, uncompressed_size, records_length)
        if problem:
            self.skip_chunk(f"{where}: {problem}; skipped")
            return
        try:
            compressed = memoryview(body)[records_start : records_start + records_length]
            records = _decompress(compression, compressed, uncompressed_size)
        except Exception as error:  # zstandard and lz4 raise their own error types for bad data
            self.skip_chunk(f"{where}: decompression failed ({_short(error)}); skipped")
            return
        if len(records) != uncompressed_size:
            more = "more than" if len(records) > uncompressed_size else f"{len(records)} bytes,"
            self.skip_chunk(
                f"{where}: {more} {uncompressed_size} bytes expected after decompression; skipped"
            )
            return
        if crc != 0 and zlib.crc32(records) != crc:
            self.skip_chunk(f"{where}: CRC mismatch (corrupted); skipped")
            return
        self.chunks += 1
        known = len(self.channels)
        times = self.add_records(records, where)
        if times is not None:
            self.add_span(offset, 9 + len(body), True, times, known)

    def skip_chunk(self, warning: str) -> None:
        self.chunks_skipped += 1
        self.warn(warning)

    def add_metadata(self, metadata: Metadata) -> None:
        self.metadata.setdefault(metadata.name, dict(metadata.metadata))

    def add_attachment(self, body: bytes) -> None:
        """Parse an Attachment record's body (every length checked against it, CRC verified)."""
        fields = _Fields(body)
        log_time_ns = fields.u64()
        create_time_ns = fields.u64()
        name = fields.text("name")
        media_type = fields.text("media type")
        data = fields.take(fields.u64(), "data")
        crc_end = fields.pos
        crc = fields.u32()
        if crc != 0 and zlib.crc32(memoryview(body)[:crc_end]) != crc:
            raise ValueError("CRC mismatch (corrupted)")
        self.attachments.append(Attachment(self.path, name, media_type, log_time_ns, create_time_ns, data))

    def report(self) -> FileReport:
        return FileReport(
            path=self.path,
            finished=self.finished,
            complete=self.finished and not self.damaged,
            library=self.library,
            messages=self.message_count,
            chunks=self.chunks,
            chunks_skipped=self.chunks_skipped,
            first_log_time_ns=self.first_log_time_ns,
            warnings=tuple(self.warnings),
        )


def _stream(data: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(data))


def _short(error: BaseException) -> str:
    text = str(error).splitlines()[0] if str(error) else ""
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def _chunk_size_problem(compression: str, uncompressed_size: int, compressed_size: int) -> str | None:
    """Why a chunk declaring these sizes is not decompressed, or None (within bounds)."""
    if uncompressed_size > MAX_CHUNK_UNCOMPRESSED_BYTES:
        return (
            f"declares {uncompressed_size} bytes uncompressed, over the limit of "
            f"{MAX_CHUNK_UNCOMPRESSED_BYTES} bytes per chunk"
        )
    if compression == "" and uncompressed_size != compressed_size:
        return f"uncompressed, but declares {uncompressed_size} bytes and holds {compressed_size}"
    if uncompressed_size > MAX_COMPRESSION_RATIO * compressed_size:
        return (
            f"declares {uncompressed_size} bytes uncompressed from {compressed_size} compressed, "
            f"over the limit of {MAX_COMPRESSION_RATIO} times"
        )
    return None


def _decompress(compression: str, data: memoryview, uncompressed_size: int) -> bytes:
    """The chunk's records: never more than `uncompressed_size` + 1 bytes (one more shows a lie)."""
    limit = uncompressed_size + 1
    if compression == "zstd":
        # Not ZstdDecompressor.decompress: it allocates whatever size the frame header declares.
        with zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True) as reader:
            pieces = []
            while limit > 0 and (piece := reader.read(limit)):
                pieces.append(piece)
                limit -= len(piece)
        return pieces[0] if len(pieces) == 1 else b"".join(pieces)
    if compression == "lz4":
        if lz4_frame is None:  # pragma: no cover
            raise ValueError("lz4 is not installed")
        return bytes(lz4_frame.LZ4FrameDecompressor().decompress(data, max_length=limit))
    if compression == "":
        return bytes(data)
    raise ValueError(f"unknown compression {compression!r}")


# ---------------------------------------------------------------------------------------------
# One file


def _read_exact(f: IO[bytes], offset: int, length: int) -> bytes:
    f.seek(offset)
    data = f.read(length)
    if len(data) != length:
        raise EOFError(f"{length} bytes wanted at byte {offset}, {len(data)} available")
    return data


def _read_record(f: IO[bytes], offset: int, limit: int) -> tuple[int, bytes]:
    """Opcode and body of the record at `offset`, which must end by `limit` (checked before reading)."""
    if offset + 9 > limit:
        raise ValueError(f"no room for a record at byte {offset}")
    opcode, length = _RECORD_HEADER.unpack(_read_exact(f, offset, 9))
    if length > limit - offset - 9:
        raise ValueError(
            f"record at byte {offset} (opcode 0x{opcode:02x}) declares {length} bytes, "
            f"{limit - offset - 9} left"
        )
    return opcode, _read_exact(f, offset + 9, length)


def _indexed_record(f: IO[bytes], offset: int, length: int, opcode: int, size: int) -> bytes:
    """The body of the record an index entry points at, checked against the entry and the file."""
    if offset < len(MAGIC) or length < 9 or offset + length > size:
        raise ValueError(f"index entry ({length} bytes) points outside the file")
    found, body = _read_record(f, offset, offset + length)
    if found != opcode or 9 + len(body) != length:
        raise ValueError(f"not the indexed record (opcode 0x{found:02x}, {len(body)} bytes)")
    return body


def _footer_intact(f: IO[bytes], size: int) -> bool:
    if size < len(MAGIC) * 2 + _FOOTER_SIZE:
        return False
    tail = _read_exact(f, size - _FOOTER_SIZE, _FOOTER_SIZE)
    opcode, length = _RECORD_HEADER.unpack_from(tail, 0)
    return tail[-len(MAGIC) :] == MAGIC and opcode == Opcode.FOOTER and length == 20


def scan_file(scan: FileScan) -> None:
    with open(scan.path, "rb") as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            if len(head) < len(MAGIC) and MAGIC.startswith(head):
                scan.warn("shorter than the MCAP magic (nothing was written); no data")
                return
            raise InputError(f"{scan.path}: not an MCAP file (bad magic bytes); expected an .mcap log")
        footer = _footer_intact(f, scan.size)
        if footer and _read_indexed(scan, f):
            return
        _read_linear(scan, f, footer)


@dataclass
class _Summary:
    """The records of a summary section that the reader uses."""

    library: str
    schemas: list[Schema] = field(default_factory=list)
    channels: list[Channel] = field(default_factory=list)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    attachment_indexes: list[AttachmentIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    statistics: Statistics | None = None


_SUMMARY_RECORDS: dict[int, tuple[str, Any]] = {
    Opcode.SCHEMA: ("schemas", Schema),
    Opcode.CHANNEL: ("channels", Channel),
    Opcode.CHUNK_INDEX: ("chunk_indexes", ChunkIndex),
    Opcode.ATTACHMENT_INDEX: ("attachment_indexes", AttachmentIndex),
    Opcode.METADATA_INDEX: ("metadata_indexes", MetadataIndex),
}


def _read_summary(f: IO[bytes], size: int) -> _Summary:
    """The header's library and the summary section, one bounded record at a time.

    Raises ValueError (or a record parsing error) when the header, the footer's offsets, a summary
    record or the summary CRC is not right.
    """
    footer_at = size - _FOOTER_SIZE
    footer = _read_exact(f, footer_at, 9 + 20)
    summary_start, _summary_offset_start, summary_crc = struct.unpack_from("<QQI", footer, 9)
    opcode, body = _read_record(f, len(MAGIC), footer_at)
    if opcode != Opcode.HEADER:
        raise ValueError(f"the first record is not a Header (opcode 0x{opcode:02x})")
    summary = _Summary(library=Header.read(_stream(body)).library)
    if summary_start == 0:
        return summary
    if not len(MAGIC) <= summary_start <= footer_at:
        raise ValueError(f"the footer puts the summary at byte {summary_start}, outside the file")
    crc = 0
    pos = summary_start
    while pos < footer_at:
        opcode, body = _read_record(f, pos, footer_at)
        crc = zlib.crc32(body, zlib.crc32(_RECORD_HEADER.pack(opcode, len(body)), crc))
        if opcode in _SUMMARY_RECORDS:
            name, record_type = _SUMMARY_RECORDS[opcode]
            getattr(summary, name).append(record_type.read(_stream(body)))
        elif opcode == Opcode.STATISTICS:
            summary.statistics = Statistics.read(_stream(body))
        pos += 9 + len(body)
    if summary_crc != 0 and zlib.crc32(footer[:-4], crc) != summary_crc:
        raise ValueError("summary CRC mismatch")
    return summary


def _read_indexed(scan: FileScan, f: IO[bytes]) -> bool:
    """Read a finished file through its summary; False (nothing read) if the summary is unusable."""
    try:
        summary = _read_summary(f, scan.size)
    except _RECORD_ERRORS as error:
        scan.warn(f"footer present but the summary is unreadable ({_short(error)}); read linearly")
        return False
    if summary.statistics is None:
        scan.warn("no summary statistics; read linearly", damage=False)
        return False
    chunk_indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    if summary.statistics.message_count and not chunk_indexes:
        scan.warn("no chunk index; read linearly", damage=False)
        return False
    if any(c.chunk_start_offset + c.chunk_length > scan.size for c in chunk_indexes):
        scan.warn("chunk index points past the end of the file; read linearly")
        return False
    scan.finished = True
    scan.library = summary.library
    for schema in summary.schemas:
        scan.add_schema(schema)
    for channel in summary.channels:
        scan.add_channel(channel)
    for index in chunk_indexes:
        offset = index.chunk_start_offset
        try:
            body = _indexed_record(f, offset, index.chunk_length, Opcode.CHUNK, scan.size)
        except (EOFError, ValueError, struct.error) as error:
            scan.skip_chunk(f"chunk at byte {offset}: {_short(error)}; skipped")
            continue
        scan.add_chunk(body, offset)
    for metadata_index in summary.metadata_indexes:
        offset = metadata_index.offset
        try:
            body = _indexed_record(f, offset, metadata_index.length, Opcode.METADATA, scan.size)
            scan.add_metadata(Metadata.read(_stream(body)))
        except _RECORD_ERRORS as error:
            scan.warn(f"metadata at byte {offset}: unreadable ({_short(error)}); skipped")
    for attachment_index in summary.attachment_indexes:
        offset = attachment_index.offset
        try:
            scan.add_attachment(
                _indexed_record(f, offset, attachment_index.length, Opcode.ATTACHMENT, scan.size)
            )
        except _RECORD_ERRORS as error:
            scan.warn(f"attachment at byte {offset}: unreadable ({_short(error)}); skipped")
    expected = summary.statistics.channel_message_counts
    for channel_id, count in scan.counts.items():
        if channel_id and expected.get(channel_id, 0) != count and channel_id in scan.channels:
            topic = scan.channels[channel_id].topic
            lost = expected.get(channel_id, 0) - count
            if lost > 0 and scan.chunks_skipped:
                scan.warn(f"{topic}: {lost} of {expected[channel_id]} messages lost in skipped chunks")
            else:
                scan.warn(f"{topic}: {count} messages read, the statistics say {expected.get(channel_id, 0)}")
    return True


def _read_linear(scan: FileScan, f: IO[bytes], footer: bool = False) -> None:
    """One pass over the records from the start, keeping every complete chunk.

    `footer`: the file ends with a footer (its summary was unusable), so a lost tail is not a crash.
    """
    size = scan.size
    pos = len(MAGIC)
    footer_seen = False
    last_good = pos
    while pos < size:
        if size - pos < 9:
            break
        f.seek(pos)
        opcode, length = _RECORD_HEADER.unpack(f.read(9))
        end = pos + 9 + length
        plausible = (opcode in _KNOWN_OPCODES or opcode >= 0x80) and end <= size
        if plausible and opcode == Opcode.CHUNK:
            f.seek(pos)
            plausible = _plausible_chunk(f.read(_CHUNK_PROBE), pos, size)
        elif plausible and opcode == Opcode.MESSAGE_INDEX:
            plausible = _plausible_message_index(f, pos, length)
        if not plausible:
            resume = _next_chunk(f, pos + 1, size)
            if resume is None:
                break  # truncated (or garbage to the end): reported below
            scan.warn(
                f"byte {pos}: invalid record header (opcode 0x{opcode:02x}, length {length}); "
                f"skipped {resume - pos} bytes to the next chunk at byte {resume}"
            )
            pos = resume
            continue
        if opcode in _READ_IN_LINEAR_PASS:
            try:
                _linear_record(scan, opcode, _read_exact(f, pos + 9, length), pos)  # within the file
            except _RECORD_ERRORS as error:
                scan.warn(f"byte {pos}: unreadable record (opcode 0x{opcode:02x}: {_short(error)}); skipped")
        elif opcode == Opcode.FOOTER:
            footer_seen = True
            last_good = end
            break
        pos = end
        last_good = end
    recovered = f"recovered {scan.chunks} complete chunks, {scan.message_count} messages"
    if not footer_seen:
        lost = size - last_good
        tail = f"; lost the tail after byte {last_good} ({lost} bytes)" if lost else ""
        state = "records unreadable before the footer" if footer else "no footer (unfinished)"
        scan.warn(f"{state}; {recovered}{tail}")
    elif not scan.warnings:
        scan.warn(f"finished file read linearly; {recovered}", damage=False)


def _linear_record(scan: FileScan, opcode: int, body: bytes, offset: int) -> None:
    if opcode == Opcode.CHUNK:
        scan.add_chunk(body, offset)
    elif opcode == Opcode.HEADER:
        scan.library = Header.read(_stream(body)).library
    elif opcode == Opcode.METADATA:
        scan.add_metadata(Metadata.read(_stream(body)))
    elif opcode == Opcode.ATTACHMENT:
        scan.add_attachment(body)
    else:  # Schema, Channel or Message outside chunks
        known = len(scan.channels)
        times = scan.add_records(_RECORD_HEADER.pack(opcode, len(body)) + body, f"record at byte {offset}")
        if times is not None:
            scan.add_span(offset, 9 + len(body), False, times, known)


def _plausible_chunk(head: bytes, pos: int, size: int) -> bool:
    """Whether a valid Chunk record header starts at `pos` (used to resynchronize).

    `head` holds the `_CHUNK_PROBE` bytes at `pos` (fewer at the end of the file). The sizes the
    chunk declares are judged later, by `add_chunk`.
    """
    if len(head) < 9 + 32 or head[0] != Opcode.CHUNK:
        return False
    _, length = _RECORD_HEADER.unpack_from(head, 0)
    start, end, _uncompressed_size, _crc, name_length = _CHUNK_HEADER.unpack_from(head, 9)
    if name_length not in (0, 3, 4) or len(head) < 9 + 32 + name_length + 8:
        return False
    if head[41 : 41 + name_length] not in (b"", b"lz4", b"zstd"):
        return False
    (records_length,) = struct.unpack_from("<Q", head, 41 + name_length)
    return bool(length == 32 + name_length + 8 + records_length and pos + 9 + length <= size and start <= end)


def _plausible_message_index(f: IO[bytes], pos: int, length: int) -> bool:
    """Whether the MessageIndex record at `pos` is consistent: channel id, then 16-byte entries."""
    f.seek(pos + 9)
    head = f.read(6)
    if len(head) < 6:
        return False
    (entries_length,) = struct.unpack_from("<I", head, 2)
    return bool(length == 6 + entries_length and entries_length % 16 == 0)


def _next_chunk(f: IO[bytes], start: int, size: int) -> int | None:
    """The offset of the next plausible Chunk record at or after `start`, or None."""
    block_start = start
    while block_start < size:
        f.seek(block_start)
        block = f.read(_SCAN_BLOCK + _CHUNK_PROBE - 1)  # overlapping, so every candidate has its probe
        i = block.find(b"\x06", 0, _SCAN_BLOCK)
        while i != -1:
            if _plausible_chunk(block[i : i + _CHUNK_PROBE], block_start + i, size):
                return block_start + i
            i = block.find(b"\x06", i + 1, _SCAN_BLOCK)
        block_start += _SCAN_BLOCK
    return None


# ---------------------------------------------------------------------------------------------
# A time window, read again


def scan_window(
    source: SpanSource,
    batches: dict[str, TopicBatches],
    wanted: frozenset[str],
    first_ns: int,
    last_ns: int,
    batch_size: int,
    spans: tuple[Span, ...] | None = None,
) -> FileScan:
    """Read the `wanted` topics' messages logged from `first_ns` to `last_ns` again into `batches`.

    Only the spans that may hold such messages are read (of `spans` if given, else all of the
    source's), each as the first scan read it: the channels it knew then, the same bounds and
    checks. The returned scan's warnings repeat what the first scan said (or say that the file
    changed since); its batches' warnings are about decoding the window.
    """
    scan = FileScan(
        path=source.path,
        size=source.size,
        batches=batches,
        wanted=wanted,
        batch_size=batch_size,
        window=(first_ns, last_ns),
    )
    channels = source.channels
    try:
        with open(source.path, "rb") as f:
            for span in source.spans if spans is None else spans:
                if not span.overlaps(first_ns, last_ns):
                    continue
                for channel_id, channel in channels[: span.channels_known]:
                    scan.known_channel(channel_id, channel)
                end = span.offset + span.length
                try:
                    if end > source.size:
                        raise ValueError(f"span ends at byte {end}, past the scanned size")
                    if span.chunk:
                        _opcode, body = _read_record(f, span.offset, end)
                        scan.add_chunk(body, span.offset)
                    else:
                        scan.add_records(
                            _read_exact(f, span.offset, span.length), f"records at byte {span.offset}"
                        )
                except (EOFError, ValueError, struct.error) as error:
                    scan.warn(f"byte {span.offset}: cannot be read again ({_short(error)}); skipped")
    except OSError as error:
        scan.warn(f"cannot be read again ({_short(error)})")
    return scan
