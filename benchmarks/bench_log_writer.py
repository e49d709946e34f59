"""RunLogger overhead against the bare mcap Writer on the same load-cell messages.

Variants (same payload dicts, zstd, 512 KiB chunks, all in this process):
  bare_flush   json.dumps + Writer.add_message, flush() every 1000 messages (1 s at 1 kHz): the same
               chunking as RunLogger, whose writer process flushes every second of log time
  bare         json.dumps + Writer.add_message, chunks closed by size only
  logger       RunLogger.log() for every message, then finish(); caller-side time = the log() calls
  logger_cols  RunLogger.log_columns() with one column per row field, 20 messages per call (1 kHz and
               a 20 ms control period: the runner's way, rig.runner.recorder), then finish()

The samples are built once as the driver gives them (`LoadCellSample`, device time included); the
payload dicts and the columns are made from them by the names in `schemas.ROW_FIELDS`, so a field
added to the sample is in every variant.

Run: .venv/bin/python benchmarks/bench_log_writer.py [--messages 200000] [--repeats 3] [--smoke]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.hw.seams import LoadCellSample
from rig.log.format import schemas as S
from rig.log.writing.writer import DEFAULT_CHUNK_SIZE, RunLogger

T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000


def make_samples(n: int) -> list[LoadCellSample]:
    """`n` load-cell samples at 1 kHz, the device clock ticking with them."""
    return [
        LoadCellSample(
            time_ns=T0_NS + i * MS,
            raw=100_000 + (i * 37) % 5000,
            force_n=1.5 + (i % 997) * 1e-3,
            seq=i,
            device_time_us=i * 1000,
        )
        for i in range(n)
    ]


def make_messages(samples: list[LoadCellSample]) -> list[tuple[int, dict]]:
    """The same samples as (log time, payload dict), as `RunLogger.log` takes them."""
    fields = S.ROW_FIELDS[S.LOADCELL]
    return [(s.time_ns, S.row_payload(S.LOADCELL, tuple(getattr(s, f) for f in fields))) for s in samples]


def run_bare(path: Path, messages: list[tuple[int, dict]], flush_every: int | None) -> dict[str, float]:
    start = time.perf_counter()
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD)
        writer.start()
        spec = S.TOPICS[S.LOADCELL]
        schema_id = writer.register_schema(spec.schema_name, "jsonschema", spec.schema_bytes)
        channel_id = writer.register_channel(S.LOADCELL, "json", schema_id)
        for i, (t, payload) in enumerate(messages):
            data = json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
            writer.add_message(channel_id, t, data, time.time_ns(), i + 1)
            if flush_every and (i + 1) % flush_every == 0:
                writer.flush()
        writer.finish()
    total = time.perf_counter() - start
    return {"caller_s": total, "total_s": total, "bytes": path.stat().st_size}


def run_logger(path: Path, messages: list[tuple[int, dict]]) -> dict[str, float]:
    start = time.perf_counter()
    logger = RunLogger(path)
    log = logger.log
    for t, payload in messages:
        log(S.LOADCELL, t, payload)
    caller = time.perf_counter() - start
    logger.finish()
    total = time.perf_counter() - start
    return {"caller_s": caller, "total_s": total, "bytes": path.stat().st_size}


def run_logger_columns(path: Path, samples: list[LoadCellSample], per_call: int = 20) -> dict[str, float]:
    fields = S.ROW_FIELDS[S.LOADCELL]
    calls = [
        ([s.time_ns for s in chunk], {f: [getattr(s, f) for s in chunk] for f in fields})
        for chunk in (samples[i : i + per_call] for i in range(0, len(samples), per_call))
    ]
    start = time.perf_counter()
    logger = RunLogger(path)
    for times_ns, columns in calls:
        logger.log_columns(S.LOADCELL, times_ns, **columns)
    caller = time.perf_counter() - start
    logger.finish()
    total = time.perf_counter() - start
    return {"caller_s": caller, "total_s": total, "bytes": path.stat().st_size}


def loadcell_messages(path: Path) -> int:
    """The number of `/rig/loadcell` messages in the file's summary."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None, f"{path}: no summary"
    ids = [i for i, channel in summary.channels.items() if channel.topic == S.LOADCELL]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)


VARIANTS = ("bare_flush", "bare", "logger", "logger_cols")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.messages, args.repeats = 2_000, 1
    samples = make_samples(args.messages)
    messages = make_messages(samples)
    n = args.messages
    best: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for name in VARIANTS:
                path = Path(tmp) / f"{name}-{repeat}.mcap"
                if name == "logger":
                    result = run_logger(path, messages)
                elif name == "logger_cols":
                    result = run_logger_columns(path, samples)
                else:
                    result = run_bare(path, messages, 1000 if name == "bare_flush" else None)
                written = loadcell_messages(path)
                if written != args.messages:
                    raise SystemExit(f"{name}: {written} load-cell messages in the file, {n} logged")
                path.unlink()
                if name not in best or result["total_s"] < best[name]["total_s"]:
                    best[name] = result
    print(f"{n} load-cell messages, best of {args.repeats}")
    print(f"{'variant':<11} {'caller s':>9} {'total s':>8} {'msg/s':>9} {'caller us/msg':>14} {'MB':>6}")
    for name, r in best.items():
        print(
            f"{name:<11} {r['caller_s']:9.3f} {r['total_s']:8.3f} {n / r['total_s']:9.0f} "
            f"{r['caller_s'] / n * 1e6:14.2f} {r['bytes'] / 1e6:6.2f}"
        )
    logger, bare_flush, bare = best["logger"], best["bare_flush"], best["bare"]
    print(
        f"ratio total logger / bare_flush: {logger['total_s'] / bare_flush['total_s']:.2f}x (target <= 1.3x)"
    )
    print(f"ratio total logger / bare:       {logger['total_s'] / bare['total_s']:.2f}x")
    print(
        f"ratio total logger_cols / bare_flush: {best['logger_cols']['total_s'] / bare_flush['total_s']:.2f}x"
    )
    print(f"ratio caller-side logger / bare_flush total: {logger['caller_s'] / bare_flush['total_s']:.2f}x")


if __name__ == "__main__":
    main()
