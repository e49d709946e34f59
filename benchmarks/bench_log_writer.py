"""RunLogger overhead against the bare mcap Writer on the same load-cell messages.

Variants (same payload dicts, zstd, 512 KiB chunks, all in this process):
  bare_flush   json.dumps + Writer.add_message, flush() every 1000 messages (1 s at 1 kHz): the same
               chunking as RunLogger, whose writer process flushes every second of log time
  bare         json.dumps + Writer.add_message, chunks closed by size only
  logger       RunLogger.log() for every message, then finish(); caller-side time = the log() calls
  logger_rows  RunLogger.log_many() with rows, 20 messages per call (the runner's way at 1 kHz and a
               20 ms control period), then finish()

Run: .venv/bin/python benchmarks/bench_log_writer.py [--messages 200000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from mcap.writer import CompressionType, Writer

from rig.log import schemas as S
from rig.log.writer import DEFAULT_CHUNK_SIZE, RunLogger

T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000


def make_messages(n: int) -> list[tuple[int, dict]]:
    return [
        (
            T0_NS + i * MS,
            S.loadcell_sample(raw=100_000 + (i * 37) % 5000, force_n=1.5 + (i % 997) * 1e-3, seq=i),
        )
        for i in range(n)
    ]


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


def run_logger_rows(path: Path, messages: list[tuple[int, dict]], per_call: int = 20) -> dict[str, float]:
    fields = S.ROW_FIELDS[S.LOADCELL]
    rows = [(t, S.LoadCellRow(*(payload[f] for f in fields))) for t, payload in messages]
    start = time.perf_counter()
    logger = RunLogger(path)
    for i in range(0, len(rows), per_call):
        logger.log_many(S.LOADCELL, rows[i : i + per_call])
    caller = time.perf_counter() - start
    logger.finish()
    total = time.perf_counter() - start
    return {"caller_s": caller, "total_s": total, "bytes": path.stat().st_size}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    messages = make_messages(args.messages)
    best: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for name in ("bare_flush", "bare", "logger", "logger_rows"):
                path = Path(tmp) / f"{name}-{repeat}.mcap"
                if name == "logger":
                    result = run_logger(path, messages)
                elif name == "logger_rows":
                    result = run_logger_rows(path, messages)
                else:
                    result = run_bare(path, messages, 1000 if name == "bare_flush" else None)
                path.unlink()
                if name not in best or result["total_s"] < best[name]["total_s"]:
                    best[name] = result
    n = args.messages
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
    rows = best["logger_rows"]
    print(f"ratio total logger_rows / bare_flush: {rows['total_s'] / bare_flush['total_s']:.2f}x")
    print(f"ratio caller-side logger / bare_flush total: {logger['caller_s'] / bare_flush['total_s']:.2f}x")


if __name__ == "__main__":
    main()
