"""The tolerant reader within bounds: hostile lengths, decompression bombs, hostile payloads, fuzzed bytes.

Valid parts are written by the `mcap` writer; the bad records are written by hand between its
chunks (a linear read) or patched over its records in place (a read through the summary). Every
read is timed and its Python allocations traced (`read_bounded`).
"""

from __future__ import annotations

import functools
import io
import json
import random
import struct
import subprocess
import sys
import time
import tracemalloc
from datetime import timedelta
from pathlib import Path

import lz4.frame
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from rig.errors import InputError
from rig.log.format import schemas as S
from rig.log.reading.frames import MAX_JSON_DEPTH
from rig.log.reading.mcap_scan import MAX_CHUNK_UNCOMPRESSED_BYTES, MAX_COMPRESSION_RATIO
from rig.log.reading.reader import RunLog, read_run

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"
T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000
HUGE = 2**60
GIB = 1 << 30
MIB = 1 << 20
SECONDS = 3.0  # each of these reads takes well under a second
PEAK_BYTES = 48 * MIB  # Python allocations while reading one of these small files


# ---------------------------------------------------------------------------------------------
# Records by hand


def record(opcode: int, body: bytes, *, length: int | None = None) -> bytes:
    """One MCAP record; `length` overrides the length it declares."""
    return struct.pack("<BQ", opcode, len(body) if length is None else length) + body


def prefixed(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def attachment_body(name: str, data: bytes, *, data_length: int | None = None) -> bytes:
    size = len(data) if data_length is None else data_length
    head = struct.pack("<QQ", T0_NS, T0_NS) + prefixed(name) + prefixed("text/plain")
    return head + struct.pack("<Q", size) + data + struct.pack("<I", 0)


def chunk_body(compressed: bytes, compression: str, uncompressed_size: int) -> bytes:
    """A Chunk record's content with no CRC (0), so that only the bounds can stop it."""
    name = compression.encode()
    head = struct.pack("<QQQII", T0_NS, T0_NS, uncompressed_size, 0, len(name)) + name
    return head + struct.pack("<Q", len(compressed)) + compressed


def message(seq: int, payload: bytes | None = None, *, log_time_ns: int | None = None) -> bytes:
    """A Message record on the load-cell channel (the writer's channel 1)."""
    t = T0_NS + seq * MS if log_time_ns is None else log_time_ns
    return record(Opcode.MESSAGE, struct.pack("<HIQQ", 1, 0, t, t) + (payload or loadcell_payload(seq)))


def zstd_zeros(total: int, *, content_size: bool = False) -> bytes:
    """A zstd frame of `total` zero bytes made by hand: 128 KiB RLE blocks, 4 bytes each (1 GiB in 32 KiB).

    `content_size`: the frame header declares `total` (zstandard's one-shot `decompress` allocates it).
    """
    block = 128 * 1024
    header = b"\x28\xb5\x2f\xfd" + (b"\xc0\x58" + struct.pack("<Q", total) if content_size else b"\x00\x58")
    count = total // block
    return header + b"".join(
        ((i == count - 1) | 2 | block << 3).to_bytes(3, "little") + b"\0" for i in range(count)
    )


def lz4_zeros(total: int) -> bytes:
    """An lz4 frame of `total` zero bytes (about 250 times smaller)."""
    compressor = lz4.frame.LZ4FrameCompressor()
    zeros = bytes(MIB)
    return b"".join(
        [compressor.begin(), *(compressor.compress(zeros) for _ in range(total // MIB)), compressor.flush()]
    )


# ---------------------------------------------------------------------------------------------
# Valid parts by the mcap writer


def loadcell_payload(seq: int) -> bytes:
    # random forces: the chunks barely compress, so a 3000-message chunk has room for a 1 GiB zstd bomb
    force_n = random.Random(seq).uniform(0, 50)
    return json.dumps(S.loadcell_sample(raw=seq, force_n=force_n, seq=seq), separators=(",", ":")).encode()


def write_log(path: Path, pieces: list[int | bytes], *, finish: bool = True) -> list[int]:
    """`/rig/loadcell` messages by the mcap writer, `seq` counting from 0, and bytes by hand.

    Each int in `pieces` is a chunk of that many messages; each bytes is written as it is between
    chunks. Two attachments come first: `rig.yaml` and `notes.txt`. Returns the offsets of the bytes.
    """
    offsets = []
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD, chunk_size=1 << 30)
        writer.start(library="bounds test")
        spec = S.TOPICS[S.LOADCELL]
        schema_id = writer.register_schema(spec.schema_name, "jsonschema", spec.schema_bytes)
        channel_id = writer.register_channel(S.LOADCELL, "json", schema_id)
        writer.add_attachment(T0_NS, T0_NS, "rig.yaml", "application/yaml", b"servos: []\n")
        writer.add_attachment(T0_NS, T0_NS, "notes.txt", "text/plain", b"nothing to note\n")
        seq = 0
        for piece in pieces:
            if isinstance(piece, int):
                for _ in range(piece):
                    t = T0_NS + seq * MS
                    writer.add_message(channel_id, t, loadcell_payload(seq), t)
                    seq += 1
                writer.flush()
            else:
                offsets.append(f.tell())
                f.write(piece)
        if finish:
            writer.finish()
    return offsets


def summary_of(path: Path):
    with open(path, "rb") as f:
        return make_reader(f).get_summary()


def patch_chunk(path: Path, index: int, compressed: bytes, compression: str, uncompressed_size: int) -> int:
    """Replace the content of the file's `index`-th chunk in place (same length: a zstd skippable frame
    pads it); returns the chunk's offset."""
    chunk = sorted(summary_of(path).chunk_indexes, key=lambda c: c.chunk_start_offset)[index]
    offset, length = chunk.chunk_start_offset, chunk.chunk_length
    padding = length - 9 - len(chunk_body(b"", compression, 0)) - len(compressed) - 8
    assert padding >= 0, "the chunk is too small for this replacement"
    skippable = struct.pack("<II", 0x184D2A50, padding) + bytes(padding)
    data = bytearray(path.read_bytes())
    data[offset + 9 : offset + length] = chunk_body(compressed + skippable, compression, uncompressed_size)
    path.write_bytes(bytes(data))
    return offset


def read_bounded(path: Path) -> tuple[RunLog, list[int]]:
    """`read_run` and the load-cell `seq` column, checked to take < SECONDS and < PEAK_BYTES (tracemalloc)."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        run = read_run(path)
        seqs = [int(s) for s in run.topic(S.LOADCELL)["seq"]]
        elapsed = time.perf_counter() - start
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert elapsed < SECONDS, f"{elapsed:.2f} s"
    assert peak < PEAK_BYTES, f"{peak / MIB:.1f} MiB"
    return run, seqs


def warned(run: RunLog, path: Path, *texts: str) -> bool:
    """Whether a warning names the file and contains every one of `texts` (one of which names the offset)."""
    return any(w.startswith(f"{path.name}: ") and all(t in w for t in texts) for w in run.warnings)


# ---------------------------------------------------------------------------------------------
# Lengths of 2**60


@pytest.mark.parametrize(
    "opcode", [Opcode.ATTACHMENT, Opcode.CHUNK, Opcode.METADATA, Opcode.MESSAGE, Opcode.SCHEMA, 0x80]
)
def test_record_declaring_2_60_bytes_is_skipped_to_the_next_chunk(tmp_path, opcode):
    path = tmp_path / "huge.mcap"
    bad = record(opcode, attachment_body("evil.txt", b"x" * 100), length=HUGE)
    (offset,) = write_log(path, [300, bad, 300], finish=False)
    run, seqs = read_bounded(path)
    assert seqs == list(range(600))
    skipped = len(bad)
    assert warned(
        run,
        path,
        f"byte {offset}: invalid record header (opcode 0x{opcode:02x}, length {HUGE}); skipped {skipped}",
    ), run.warnings
    assert [a.name for a in run.attachments] == ["rig.yaml", "notes.txt"]


def test_attachment_data_declaring_2_60_bytes_is_skipped(tmp_path):
    path = tmp_path / "huge.mcap"
    bad = record(Opcode.ATTACHMENT, attachment_body("evil.txt", b"x" * 10, data_length=HUGE))
    (offset,) = write_log(path, [300, bad, 300], finish=False)
    run, seqs = read_bounded(path)
    assert seqs == list(range(600))
    assert warned(
        run, path, f"byte {offset}: unreadable record (opcode 0x09: ValueError: data declares {HUGE} bytes"
    )
    assert [a.name for a in run.attachments] == ["rig.yaml", "notes.txt"]


@pytest.mark.parametrize("field", ["record length", "data length"])
def test_indexed_attachment_declaring_2_60_bytes_is_skipped(tmp_path, field):
    path = tmp_path / "huge.mcap"
    write_log(path, [300, 300])
    (notes,) = [a for a in summary_of(path).attachment_indexes if a.name == "notes.txt"]
    at = notes.offset + 1 if field == "record length" else notes.offset + 9 + 16 + 4 + 9 + 4 + 10
    data = bytearray(path.read_bytes())
    data[at : at + 8] = struct.pack("<Q", HUGE)
    path.write_bytes(bytes(data))

    run, seqs = read_bounded(path)
    assert run.reports[0].finished and not run.complete
    assert seqs == list(range(600))
    (warning,) = run.warnings
    assert warning.startswith(f"huge.mcap: attachment at byte {notes.offset}: unreadable (ValueError: ")
    assert str(HUGE) in warning and warning.endswith("; skipped")
    assert [a.name for a in run.attachments] == ["rig.yaml"]


# ---------------------------------------------------------------------------------------------
# Decompression bombs

ZSTD_BOMBS = {
    "over the size limit": (
        zstd_zeros(GIB),
        GIB,
        f"declares {GIB} bytes uncompressed, over the limit of {MAX_CHUNK_UNCOMPRESSED_BYTES} bytes",
    ),
    "over the ratio": (zstd_zeros(8 * MIB), 200 * MIB, f"over the limit of {MAX_COMPRESSION_RATIO} times"),
    "frame bigger than declared": (
        zstd_zeros(GIB),
        MIB,
        f"more than {MIB} bytes expected after decompression",
    ),
    "frame header declares more": (
        zstd_zeros(GIB, content_size=True),
        MIB,
        f"more than {MIB} bytes expected after decompression",
    ),
}


@pytest.mark.parametrize("finished", [False, True], ids=["linear", "indexed"])
@pytest.mark.parametrize("bomb", list(ZSTD_BOMBS))
def test_zstd_bomb_chunk_is_skipped_in_bounded_time_and_memory(tmp_path, bomb, finished):
    compressed, declared, expected = ZSTD_BOMBS[bomb]
    path = tmp_path / "bomb.mcap"
    if finished:
        write_log(path, [300, 3000, 300])
        offset = patch_chunk(path, 1, compressed, "zstd", declared)
        survivors = [*range(300), *range(3300, 3600)]
    else:
        (offset,) = write_log(
            path, [300, record(Opcode.CHUNK, chunk_body(compressed, "zstd", declared)), 300], finish=False
        )
        survivors = list(range(600))
    run, seqs = read_bounded(path)
    assert seqs == survivors
    assert warned(run, path, f"chunk at byte {offset}: ", expected, "; skipped"), run.warnings
    assert run.reports[0].chunks_skipped == 1 and run.reports[0].chunks == 2
    if finished:
        assert warned(run, path, "/rig/loadcell: 3000 of 3600 messages lost in skipped chunks")


def test_lz4_bomb_chunk_is_decompressed_no_further_than_declared(tmp_path):
    compressed = lz4_zeros(64 * MIB)
    path = tmp_path / "bomb.mcap"
    (offset,) = write_log(
        path, [300, record(Opcode.CHUNK, chunk_body(compressed, "lz4", MIB)), 300], finish=False
    )
    run, seqs = read_bounded(path)
    assert seqs == list(range(600))
    assert warned(run, path, f"chunk at byte {offset}: more than {MIB} bytes expected after decompression")


def test_uncompressed_chunk_must_hold_what_it_declares(tmp_path):
    inner = message(300)
    path = tmp_path / "raw.mcap"
    (offset,) = write_log(
        path, [300, record(Opcode.CHUNK, chunk_body(inner, "", 10 * len(inner))), 300], finish=False
    )
    run, seqs = read_bounded(path)
    assert seqs == list(range(600))
    assert warned(run, path, f"chunk at byte {offset}: uncompressed, but declares {10 * len(inner)} bytes")


# ---------------------------------------------------------------------------------------------
# Damage inside a chunk and hostile payloads


def test_unreadable_records_inside_a_chunk_are_skipped_and_the_rest_kept(tmp_path):
    short_message = record(Opcode.MESSAGE, b"\x01\x00")  # shorter than a message header
    bad_channel = record(Opcode.CHANNEL, b"\xff" * 7)  # the topic's length runs past the record
    inner = short_message + bad_channel + message(999)
    path = tmp_path / "inner.mcap"
    (offset,) = write_log(
        path, [300, record(Opcode.CHUNK, chunk_body(inner, "", len(inner))), 300], finish=False
    )
    run, seqs = read_bounded(path)
    assert seqs == [*range(600), 999]
    assert warned(run, path, f"chunk at byte {offset}: 2 unreadable records (damaged); skipped")


def test_hostile_payloads_are_dropped_with_warnings(tmp_path):
    """Nesting that would overflow pyarrow's stack, invalid UTF-8 in a key, a time past 2**63 ns."""
    hostile = [
        message(1000, b'{"seq":' + b"[" * 100_000 + b"]" * 100_000 + b"}"),
        message(1001, b'{"seq":1001,"raw":1,"x":' + b"[" * MAX_JSON_DEPTH + b"]" * MAX_JSON_DEPTH + b"}"),
        message(1002, b'{"seq":1002,"\xff":1}'),
        message(1003, log_time_ns=(1 << 63) + 5),
    ]
    inner = b"".join(hostile) + message(1004)
    path = tmp_path / "payloads.mcap"
    write_log(path, [300, record(Opcode.CHUNK, chunk_body(inner, "", len(inner)))], finish=False)
    run, seqs = read_bounded(path)
    assert seqs == [*range(300), 1004]
    (rows,) = [w for w in run.warnings if "decoded row by row" in w]
    assert rows.startswith(
        "/rig/loadcell: a batch did not parse as columns (invalid UTF-8, nested deeper than "
        f"{MAX_JSON_DEPTH} levels); decoded row by row; 1 messages were not JSON objects and were dropped; "
        f"2 messages nested deeper than {MAX_JSON_DEPTH} levels were dropped"
    )
    assert "/rig/loadcell: 1 messages with a time past 2**63 ns (damaged); dropped" in run.warnings


# ---------------------------------------------------------------------------------------------
# Fuzzing: any bytes give a result or an InputError, quickly


@functools.cache
def small_logs() -> tuple[bytes, ...]:
    """Small valid logs: zstd with CRCs (RunLogger's settings), and uncompressed or lz4 without CRCs,
    so that mutations reach the record parser and the JSON decoding."""
    logs = []
    for compression, crcs in (
        (CompressionType.ZSTD, True),
        (CompressionType.NONE, False),
        (CompressionType.LZ4, False),
    ):
        buffer = io.BytesIO()
        writer = Writer(buffer, compression=compression, enable_crcs=crcs, chunk_size=2000)
        writer.start(library="fuzz")
        channels = {}
        for topic in (S.LOADCELL, S.TRIAL_STATE, S.LOG):
            spec = S.TOPICS[topic]
            schema_id = writer.register_schema(spec.schema_name, "jsonschema", spec.schema_bytes)
            channels[topic] = writer.register_channel(topic, "json", schema_id)
        writer.add_metadata("session", {"run_id": "fuzz", "seed": "1"})
        writer.add_attachment(T0_NS, T0_NS, "rig.yaml", "application/yaml", b"servos: []\n")
        for i in range(60):
            t = T0_NS + i * MS
            writer.add_message(channels[S.LOADCELL], t, loadcell_payload(i), t)
            if i % 20 == 0:
                state = {"trial_id": 1, "phase": "ramp_fast", "step": "ramp_until_slip"}
                writer.add_message(channels[S.TRIAL_STATE], t, json.dumps(state).encode(), t)
                line = {
                    "timestamp": {"sec": 1, "nsec": 2},
                    "level": 2,
                    "message": "[x",
                    "name": "rig",
                    "file": "",
                    "line": 1,
                }
                writer.add_message(channels[S.LOG], t, json.dumps(line).encode(), t)
        writer.finish()
        logs.append(buffer.getvalue())
    return tuple(logs)


TOKENS = [b"[[[[[[[[", b'{"a":{"a":', b"1e999", b"99999999999999999999999", b"NaN", b"null", b"}", b"]",
          b'"seq"', b'"\\ud800"', b"\xff\xfe", b'"log_time_ns"', b'"a.b"']  # fmt: skip
NUMBERS = [0, 1, 9, 255, 2**16, 2**31, 2**32 - 1, 2**32, 2**40, 2**60, 2**63, 2**64 - 1]
MUTATION = st.one_of(
    st.tuples(st.just("xor"), st.floats(0, 1, exclude_max=True), st.integers(1, 255)),
    st.tuples(st.just("u64"), st.floats(0, 1, exclude_max=True), st.sampled_from(NUMBERS)),
    st.tuples(st.just("u32"), st.floats(0, 1, exclude_max=True), st.sampled_from(NUMBERS[:7])),
    st.tuples(st.just("cut"), st.floats(0, 1), st.just(b"")),
    st.tuples(st.just("delete"), st.floats(0, 1, exclude_max=True), st.integers(1, 64)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=32)),
    st.tuples(st.just("overwrite"), st.floats(0, 1, exclude_max=True), st.sampled_from(TOKENS)),
)


def mutate(data: bytes, mutations: list[tuple[str, float, object]]) -> bytes:
    out = bytearray(data)
    for kind, where, arg in mutations:
        if not out:
            break
        pos = int(where * len(out))
        if kind == "xor":
            out[min(pos, len(out) - 1)] ^= arg  # type: ignore[operator]
        elif kind in ("u64", "u32"):
            size = 8 if kind == "u64" else 4
            pos = min(pos, max(len(out) - size, 0))
            out[pos : pos + size] = int(arg).to_bytes(size, "little")  # type: ignore[call-overload]
        elif kind == "cut":
            del out[pos:]
        elif kind == "delete":
            del out[pos : pos + arg]  # type: ignore[operator]
        else:  # insert, overwrite
            out[pos : pos if kind == "insert" else pos + len(arg)] = arg  # type: ignore[arg-type]
    return bytes(out)


def read_everything(path: Path) -> None:
    """What replay asks of the reader: every topic as a frame, metadata, attachments, warnings."""
    try:
        run = read_run(path)
        for topic in run.topics:
            run.topic(topic)
        assert isinstance(run.metadata, dict) and isinstance(run.attachments, list)
        assert all(isinstance(w, str) for w in run.warnings)
    except InputError:
        pass


@settings(max_examples=150, deadline=timedelta(seconds=2), suppress_health_check=[HealthCheck.too_slow])
@given(base=st.integers(0, 2), mutations=st.lists(MUTATION, min_size=1, max_size=4))
def test_fuzzed_logs_read_or_raise_input_error_within_a_deadline(tmp_path_factory, base, mutations):
    path = tmp_path_factory.mktemp("fuzz") / "f.mcap"
    path.write_bytes(mutate(small_logs()[base], mutations))
    read_everything(path)


@pytest.mark.slow
@settings(max_examples=1200, deadline=timedelta(seconds=2), suppress_health_check=[HealthCheck.too_slow])
@given(base=st.integers(0, 2), mutations=st.lists(MUTATION, min_size=1, max_size=8))
def test_fuzzed_logs_at_length(tmp_path_factory, base, mutations):
    path = tmp_path_factory.mktemp("fuzz") / "f.mcap"
    path.write_bytes(mutate(small_logs()[base], mutations))
    read_everything(path)


# ---------------------------------------------------------------------------------------------
# `rig replay` on a damaged run log: exit code, warnings, time and peak RSS in a fresh process

PROBE = """\
import json, sys, time
from rig.cli import main
start = time.perf_counter()
code = main(sys.argv[1:])
elapsed = time.perf_counter() - start
with open("/proc/self/status") as status:  # VmHWM: this process's own peak RSS (ru_maxrss is inherited)
    peak_kib = next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))
print(json.dumps({"code": code, "elapsed_s": elapsed, "peak_mib": peak_kib / 1024}), file=sys.stderr)
"""


def replay_probe(*argv: str) -> tuple[dict, str, dict]:
    """Run `rig *argv` in a fresh interpreter: (its measures, its stderr, its stdout as JSON or {})."""
    done = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=120)
    *lines, last = done.stderr.strip().splitlines()
    stdout = json.loads(done.stdout) if done.stdout.strip().startswith("{") else {}
    return json.loads(last), "\n".join(lines), stdout


@pytest.fixture(scope="module")
def smoke_log(tmp_path_factory, run_on_simulated_rig) -> Path:
    report, _ = run_on_simulated_rig(
        PROTOCOLS / "smoke.yaml", tmp_path_factory.mktemp("smoke"), run_id="smoke"
    )
    assert report.exit_code == 0
    return Path(report.log)


@pytest.mark.slow
@pytest.mark.subprocess
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux)")
def test_replay_of_a_bombed_log_exits_0_with_warnings_in_bounded_time_and_memory(smoke_log, tmp_path):
    chunks = sorted(summary_of(smoke_log).chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = smoke_log.read_bytes()
    at = chunks[1].chunk_start_offset
    last = chunks[-1]
    data_end = last.chunk_start_offset + last.chunk_length + last.message_index_length
    bomb = record(Opcode.CHUNK, chunk_body(zstd_zeros(GIB), "zstd", GIB))
    evil = record(Opcode.ATTACHMENT, attachment_body("evil.txt", b"x", data_length=HUGE))
    damaged = tmp_path / "smoke.mcap"
    damaged.write_bytes(data[:at] + bomb + evil + data[at:data_end])  # unfinished: read linearly

    clean, _, _ = replay_probe("replay", str(smoke_log), "--json")
    measured, stderr, out = replay_probe("replay", str(damaged), "--json")
    assert clean["code"] == 0 and measured["code"] == 0, stderr
    assert "Traceback" not in stderr
    assert [t["trial_id"] for t in out["trials"]] == [1, 2]
    assert any(f"smoke.mcap: chunk at byte {at}: declares {GIB} bytes" in w for w in out["warnings"])
    assert any(
        f"smoke.mcap: byte {at + len(bomb)}: unreadable record (opcode 0x09" in w for w in out["warnings"]
    )
    assert measured["elapsed_s"] < 2 * clean["elapsed_s"] + 3  # side by side; loose: the machine is shared
    assert measured["peak_mib"] < clean["peak_mib"] + 64, (measured, clean)

    bomb_only = tmp_path / "bomb_only.mcap"
    bomb_only.write_bytes(data[: chunks[0].chunk_start_offset] + bomb)
    measured, stderr, _ = replay_probe("replay", str(bomb_only))
    assert measured["code"] == 2
    (line,) = stderr.splitlines()
    assert line.startswith(
        f"rig: error: {bomb_only}: no rig messages could be read: bomb_only.mcap: chunk at byte"
    )
