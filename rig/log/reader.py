"""The tolerant run reader: one or more MCAP files (finished, crashed or damaged) into DataFrames.

A finished file (footer, summary and chunk indexes intact) is read through its index: each chunk
listed in the summary is read at its offset, and the counts are checked against the Statistics
record. Any other file (a crashed run with no footer, a truncated copy, a damaged summary) is read
in one linear pass over its records, which keeps every complete chunk and says in `warnings` what
was lost. Both paths decompress chunks themselves and check their CRC, so a corrupted chunk is
skipped with a warning and the others still come back. A linear pass that meets garbage (a damaged
record header) searches forward for the next valid chunk and reports the bytes it skipped.

(mcap 1.6.0's own readers were not enough here: `make_reader(...).iter_messages()` yields nothing
from an unfinished file, `StreamReader` stops at the first bad record, and
`iter_messages(log_time_order=False)` decompresses the whole file before the first message.)

Messages are kept per topic as raw payloads and decoded in column batches (`rig.log.frames`).
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import pandas as pd
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Attachment as McapAttachment
from mcap.records import Channel, Header, Metadata, Schema

from rig.errors import InputError
from rig.log.frames import DEFAULT_BATCH_SIZE, TopicBatches, empty_frame

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
_MAX_UNCOMPRESSED_CHUNK = 1 << 31
_SCAN_BLOCK = 1 << 22
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


@dataclass
class _Channel:
    topic: str
    message_encoding: str
    schema_name: str


@dataclass
class _FileScan:
    """The state of reading one file; messages go to the run-wide per-topic batches."""

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
        self.channels[channel.id] = _Channel(channel.topic, channel.message_encoding, schema_name)
        sink = None
        if self.wanted is None or channel.topic in self.wanted:
            if channel.message_encoding == "json":
                sink = self.batches.get(channel.topic)
                if sink is None:
                    sink = self.batches[channel.topic] = TopicBatches(channel.topic, self.batch_size)
            else:
                self.warn(
                    f"{channel.topic}: encoding {channel.message_encoding!r} is not JSON; not decoded",
                    damage=False,
                )
        self.sinks[channel.id] = sink
        self.counts.setdefault(channel.id, 0)

    def add_records(self, data: bytes, where: str) -> None:
        """Parse the records of a chunk (or a run of top-level records); messages go to the batches."""
        sinks = self.sinks
        counts = self.counts
        unpack_record = _RECORD_HEADER.unpack_from
        unpack_message = _MESSAGE_HEADER.unpack_from
        first_time = self.first_log_time_ns
        size = len(data)
        pos = 0
        while pos + 9 <= size:
            opcode, length = unpack_record(data, pos)
            body = pos + 9
            end = body + length
            if end > size:
                break
            if opcode == 5:  # Message
                channel_id, _sequence, log_time, publish_time = unpack_message(data, body)
                sink = sinks.get(channel_id)
                if sink is not None:
                    sink.payloads.append(data[body + 22 : end])
                    sink.log_times.append(log_time)
                    sink.publish_times.append(publish_time)
                if channel_id in counts:
                    counts[channel_id] += 1
                else:
                    counts[0] = counts.get(0, 0) + 1
                if first_time is None or log_time < first_time:
                    first_time = log_time
            elif opcode == Opcode.SCHEMA:
                self.add_schema(Schema.read(_stream(data[body:end])))
            elif opcode == Opcode.CHANNEL:
                self.add_channel(Channel.read(_stream(data[body:end])))
            pos = end
        self.first_log_time_ns = first_time
        if pos != size:
            self.warn(f"{where}: records end {size - pos} bytes early (damaged); kept what came before")
        for sink in self.batches.values():
            if len(sink.payloads) >= sink.batch_size:
                sink.decode_pending()

    def add_chunk(self, body: bytes, offset: int) -> None:
        """Decompress one Chunk record's content, check its CRC and parse its records."""
        where = f"chunk at byte {offset}"
        try:
            _start, _end, uncompressed_size, crc, name_length = _CHUNK_HEADER.unpack_from(body, 0)
            compression = bytes(body[32 : 32 + name_length]).decode()
            (records_length,) = struct.unpack_from("<Q", body, 32 + name_length)
            records_start = 40 + name_length
            if records_start + records_length > len(body):
                raise ValueError("records run past the end of the chunk")
            compressed = body[records_start : records_start + records_length]
            records = _decompress(compression, compressed, uncompressed_size)
        except Exception as error:
            self.chunks_skipped += 1
            self.warn(f"{where}: decompression failed ({_short(error)}); skipped")
            return
        if len(records) != uncompressed_size:
            self.chunks_skipped += 1
            self.warn(
                f"{where}: {len(records)} bytes after decompression, {uncompressed_size} expected; skipped"
            )
            return
        if crc != 0 and zlib.crc32(records) != crc:
            self.chunks_skipped += 1
            self.warn(f"{where}: CRC mismatch (corrupted); skipped")
            return
        self.chunks += 1
        self.add_records(records, where)

    def add_metadata(self, metadata: Metadata) -> None:
        self.metadata.setdefault(metadata.name, dict(metadata.metadata))

    def add_attachment(self, attachment: McapAttachment) -> None:
        self.attachments.append(
            Attachment(
                file=self.path,
                name=attachment.name,
                media_type=attachment.media_type,
                log_time_ns=attachment.log_time,
                create_time_ns=attachment.create_time,
                data=bytes(attachment.data),
            )
        )

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


def _decompress(compression: str, data: bytes, uncompressed_size: int) -> bytes:
    if uncompressed_size > _MAX_UNCOMPRESSED_CHUNK:
        raise ValueError(f"implausible uncompressed size {uncompressed_size}")
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=uncompressed_size)
    if compression == "lz4":
        if lz4_frame is None:  # pragma: no cover
            raise ValueError("lz4 is not installed")
        return bytes(lz4_frame.decompress(data))
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


def _footer_intact(f: IO[bytes], size: int) -> bool:
    if size < len(MAGIC) * 2 + _FOOTER_SIZE:
        return False
    tail = _read_exact(f, size - _FOOTER_SIZE, _FOOTER_SIZE)
    opcode, length = _RECORD_HEADER.unpack_from(tail, 0)
    return tail[-len(MAGIC) :] == MAGIC and opcode == Opcode.FOOTER and length == 20


def _scan_file(scan: _FileScan) -> None:
    with open(scan.path, "rb") as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            if len(head) < len(MAGIC) and MAGIC.startswith(head):
                scan.warn("shorter than the MCAP magic (nothing was written); no data")
                return
            raise InputError(f"{scan.path}: not an MCAP file (bad magic bytes); expected an .mcap log")
        if _footer_intact(f, scan.size) and _read_indexed(scan, f):
            return
        _read_linear(scan, f)


def _read_indexed(scan: _FileScan, f: IO[bytes]) -> bool:
    """Read a finished file through its summary; False (nothing read) if the summary is unusable."""
    try:
        f.seek(0)
        reader = SeekingReader(f)
        header = reader.get_header()
        summary = reader.get_summary()
    except (McapError, EOFError, ValueError, struct.error, UnicodeDecodeError) as error:
        scan.warn(f"footer present but the summary is unreadable ({_short(error)}); read linearly")
        return False
    if summary is None or summary.statistics is None:
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
    scan.library = header.library
    for schema in summary.schemas.values():
        scan.add_schema(schema)
    for channel in summary.channels.values():
        scan.add_channel(channel)
    for index in chunk_indexes:
        offset = index.chunk_start_offset
        try:
            record = _read_exact(f, offset, index.chunk_length)
            opcode, length = _RECORD_HEADER.unpack_from(record, 0)
            if opcode != Opcode.CHUNK or 9 + length != index.chunk_length:
                raise ValueError(f"not a chunk record (opcode 0x{opcode:02x}, length {length})")
        except (EOFError, ValueError, struct.error) as error:
            scan.chunks_skipped += 1
            scan.warn(f"chunk at byte {offset}: {_short(error)}; skipped")
            continue
        scan.add_chunk(record[9:], offset)
    try:
        for metadata in reader.iter_metadata():
            scan.add_metadata(metadata)
        for attachment in reader.iter_attachments():
            scan.add_attachment(attachment)
    except (McapError, EOFError, ValueError, struct.error, UnicodeDecodeError) as error:
        scan.warn(f"metadata or attachments unreadable ({_short(error)})")
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


def _read_linear(scan: _FileScan, f: IO[bytes]) -> None:
    """One pass over the records from the start, keeping every complete chunk."""
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
            plausible = _plausible_chunk(f, pos, size)
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
            f.seek(pos + 9)
            body = f.read(length)
            try:
                _linear_record(scan, opcode, body, pos)
            except (McapError, EOFError, ValueError, struct.error, UnicodeDecodeError) as error:
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
        scan.warn(f"no footer (unfinished); {recovered}{tail}")
    elif not scan.warnings:
        scan.warn(f"finished file read linearly; {recovered}", damage=False)


def _linear_record(scan: _FileScan, opcode: int, body: bytes, offset: int) -> None:
    if opcode == Opcode.CHUNK:
        scan.add_chunk(body, offset)
    elif opcode == Opcode.HEADER:
        scan.library = Header.read(_stream(body)).library
    elif opcode == Opcode.METADATA:
        scan.add_metadata(Metadata.read(_stream(body)))
    elif opcode == Opcode.ATTACHMENT:
        scan.add_attachment(McapAttachment.read(_stream(body)))
    else:  # Schema, Channel or Message outside chunks
        scan.add_records(_RECORD_HEADER.pack(opcode, len(body)) + body, f"record at byte {offset}")


def _plausible_chunk(f: IO[bytes], pos: int, size: int) -> bool:
    """Whether a valid Chunk record header starts at `pos` (used to resynchronize)."""
    f.seek(pos)
    head = f.read(9 + 32 + 4 + 8)
    if len(head) < 9 + 32 or head[0] != Opcode.CHUNK:
        return False
    _, length = _RECORD_HEADER.unpack_from(head, 0)
    start, end, uncompressed_size, _crc, name_length = _CHUNK_HEADER.unpack_from(head, 9)
    if name_length not in (0, 3, 4) or len(head) < 9 + 32 + name_length + 8:
        return False
    if head[41 : 41 + name_length] not in (b"", b"lz4", b"zstd"):
        return False
    (records_length,) = struct.unpack_from("<Q", head, 41 + name_length)
    return bool(
        length == 32 + name_length + 8 + records_length
        and pos + 9 + length <= size
        and start <= end
        and uncompressed_size <= _MAX_UNCOMPRESSED_CHUNK
    )


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
        block = f.read(_SCAN_BLOCK)
        i = block.find(b"\x06")
        while i != -1:
            if _plausible_chunk(f, block_start + i, size):
                return block_start + i
            i = block.find(b"\x06", i + 1)
        block_start += len(block)
    return None


# ---------------------------------------------------------------------------------------------
# A run


class RunLog:
    """The messages, metadata and attachments of one run, from one or more MCAP files."""

    def __init__(
        self,
        reports: list[FileReport],
        batches: dict[str, TopicBatches],
        counts: dict[str, int],
        schema_names: dict[str, str],
        metadata_by_file: dict[Path, dict[str, dict[str, str]]],
        attachments: list[Attachment],
        warnings: list[str],
    ) -> None:
        self.reports = reports
        self.files = [r.path for r in reports]
        self.complete = bool(reports) and all(r.complete for r in reports)
        self.message_counts = counts
        self.schema_names = schema_names
        self.metadata_by_file = metadata_by_file
        self.attachments = attachments
        self.warnings = warnings
        self._batches = batches
        self._frames: dict[str, pd.DataFrame] = {}

    @property
    def topics(self) -> list[str]:
        """Topics present in the files, sorted."""
        return sorted(self.message_counts)

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name; for a name in several files, the earliest file's record."""
        merged: dict[str, dict[str, str]] = {}
        for per_file in self.metadata_by_file.values():
            for name, values in per_file.items():
                merged.setdefault(name, values)
        return merged

    def topic(self, name: str) -> pd.DataFrame:
        """One topic's messages, indexed by UTC log time and sorted (stable) by it.

        Columns: `log_time_ns`, `publish_time_ns` and the payload fields (`{sec, nsec}` and other
        objects flattened to `a.b`). A rig topic without messages gives an empty frame with its
        declared columns; an unknown topic raises `KeyError`. The frame is cached: copy it before
        changing it.
        """
        if name not in self._frames:
            batches = self._batches.get(name)
            if batches is not None:
                self._frames[name] = batches.frame()
                self.warnings.extend(w for w in batches.warnings if w not in self.warnings)
                del self._batches[name]
            else:
                from rig.log import schemas

                if name not in schemas.TOPICS and name not in self.message_counts:
                    raise KeyError(
                        f"no topic {name!r} in this run; topics: {', '.join(self.topics) or 'none'}"
                    )
                self._frames[name] = empty_frame(name)
        return self._frames[name]


def mcap_files(paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The MCAP files named by a path, a directory (its `*.mcap`) or a list of either."""
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    files: list[Path] = []
    for item in paths:
        path = Path(item)
        if path.is_dir():
            found = sorted(path.glob("*.mcap"))
            if not found:
                raise InputError(f"{path}: no .mcap files in this directory")
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            raise InputError(f"{path}: no such file or directory")
    if not files:
        raise InputError("no MCAP files given")
    return list(dict.fromkeys(files))


def read_run(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    *,
    topics: Iterable[str] | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> RunLog:
    """Read one run from MCAP files (a path, a directory or a list), tolerating crashes and damage.

    :param topics: decode only these topics (all are still counted); None decodes every topic.
    :param batch_size: payloads decoded per batch; bounds the memory of pending raw payloads.
    """
    wanted = None if topics is None else frozenset(topics)
    batches: dict[str, TopicBatches] = {}
    scans: list[_FileScan] = []
    for path in mcap_files(paths):
        scan = _FileScan(
            path=path, size=path.stat().st_size, batches=batches, wanted=wanted, batch_size=batch_size
        )
        if scan.size == 0:
            scan.warn("empty file (nothing was written); no data")
        else:
            _scan_file(scan)
        if scan.counts.get(0):
            scan.warn(f"{scan.counts[0]} messages on channels whose Channel record was lost; skipped")
        scans.append(scan)
    for sink in batches.values():
        sink.decode_pending()

    scans.sort(key=lambda s: (s.first_log_time_ns is None, s.first_log_time_ns or 0, str(s.path)))
    counts: dict[str, int] = {}
    schema_names: dict[str, str] = {}
    for scan in scans:
        for channel_id, channel in scan.channels.items():
            counts[channel.topic] = counts.get(channel.topic, 0) + scan.counts.get(channel_id, 0)
            schema_names.setdefault(channel.topic, channel.schema_name)
    warnings = [w for scan in scans for w in scan.warnings]
    warnings += [w for sink in batches.values() for w in sink.warnings]
    return RunLog(
        reports=[scan.report() for scan in scans],
        batches=batches,
        counts=counts,
        schema_names=schema_names,
        metadata_by_file={scan.path: scan.metadata for scan in scans},
        attachments=[a for scan in scans for a in scan.attachments],
        warnings=warnings,
    )
