"""Replay speed and memory: read_run into a DataFrame against a bare linear StreamReader pass.

Writes a log of 1,000,000 load-cell messages (RunLogger, as the rig writes it) in a temp dir, then runs
each variant in a fresh subprocess, so that the RSS high-water mark (ru_maxrss) is the variant's own:
  bare_stream   mcap StreamReader(f).records, json.loads of every Message into per-field lists
  bare_indexed  make_reader(f).iter_messages() (log-time order), json.loads into per-field lists
  read_run      rig.log.reading.reader.read_run(path).topic("/rig/loadcell"): a DataFrame indexed by time

With --default-run, the log is instead that of the default run (`rig run protocols/joint_estimation.yaml
--seed 0`, 1000 load-cell samples/s, every topic), and the variants are the analysis library's:
  bare_iterate  make_reader(f).iter_messages() over every message (no decoding)
  bare_decode   the same, json.loads of every payload
  open_log      rig.analysis.open_log(path): the run's settings, trials, slips, estimates (one scan)
  trials        open_log(path).trials: the above and every trial re-detected (its samples read again)
  loadcell      open_log(path).loadcell: the above without re-detection, and every load-cell sample
Variants run alternately, each in a fresh process, `--repeats` times; the ratios are of medians.

Run: .venv/bin/python benchmarks/bench_log_reader.py [--messages 1000000] [--repeats 2]
     .venv/bin/python benchmarks/bench_log_reader.py --default-run --repeats 5
     .venv/bin/python benchmarks/bench_log_reader.py --smoke  (both, small: the log of a one-trial run and
         2,000 messages, each set of variants in one child process)
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from smoke_mode import SMOKE_HELP, short_protocol  # benchmarks/ is the script's directory

T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000
VARIANTS = ("bare_stream", "bare_indexed", "read_run")
RUN_VARIANTS = ("bare_iterate", "bare_decode", "open_log", "trials", "loadcell")
ROOT = Path(__file__).resolve().parent.parent
DEFAULT_PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"
# The parent stays small (stdlib only): Linux keeps ru_maxrss across fork and exec, so a child's
# figure would otherwise start from the parent's high-water mark.


def generate(path: Path, n: int) -> None:
    from rig.log.format import schemas as S
    from rig.log.writing.writer import RunLogger

    with RunLogger(path) as log:
        for i in range(n):
            payload = S.loadcell_sample(raw=100_000 + (i * 37) % 5000, force_n=1.5 + (i % 997) * 1e-3, seq=i)
            log.log(S.LOADCELL, T0_NS + i * MS, payload)


def generate_default_run(path: Path, protocol: Path = DEFAULT_PROTOCOL) -> None:
    """The default run's log (seed 0) at `path`, written by this tree's `rig run` (`protocol`: another's)."""
    command = [sys.executable, "-m", "rig.cli", "run", str(protocol)]
    command += ["--seed", "0", "--out", str(path.parent), "--run-id", path.stem, "--json"]
    subprocess.run(command, check=True, capture_output=True, timeout=900)


def run_library_variant(name: str, path: Path) -> dict[str, float]:
    start = time.perf_counter()
    if name in ("bare_iterate", "bare_decode"):
        from mcap.reader import make_reader

        count = 0
        with open(path, "rb") as f:
            for _schema, _channel, message in make_reader(f).iter_messages():
                if name == "bare_decode":
                    json.loads(message.data)
                count += 1
    else:
        from rig.analysis import open_log

        run = open_log(path)
        if name == "trials":
            count = len(run.trials)
        elif name == "loadcell":
            count = len(run.loadcell)
        else:
            count = len(run.files)
    elapsed = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"seconds": elapsed, "messages": count, "peak_rss_mb": peak_mb}


def variant_results(
    names: tuple[str, ...], child: list[str], one_process: bool
) -> dict[str, dict[str, float]]:
    """Each variant's result from `child --variant NAME` (a JSON line): a process per variant, or one for all.

    One process for all (the smoke mode) runs the same variant code, without a fresh process each.
    """
    results: dict[str, dict[str, float]] = {}
    for group in [names] if one_process else [(name,) for name in names]:
        done = subprocess.run(
            [*child, "--variant", *group], capture_output=True, text=True, check=True, timeout=600
        )
        for name, line in zip(group, done.stdout.splitlines(), strict=True):
            results[name] = json.loads(line)
    return results


def default_run_main(repeats: int, smoke: bool = False) -> None:
    import statistics

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        generate_default_run(path, short_protocol(Path(tmp), trials=1) if smoke else DEFAULT_PROTOCOL)
        print(f"default run log: {path.stat().st_size / 1e6:.1f} MB")
        times: dict[str, list[float]] = {name: [] for name in RUN_VARIANTS}
        peaks: dict[str, float] = {}
        for _ in range(repeats):
            results = variant_results(RUN_VARIANTS, [sys.executable, __file__, "--file", str(path)], smoke)
            for name, result in results.items():
                times[name].append(result["seconds"])
                peaks[name] = max(peaks.get(name, 0.0), result["peak_rss_mb"])
    medians = {name: statistics.median(values) for name, values in times.items()}
    print(f"median of {repeats}, variants alternating; peak RSS is the largest seen")
    print(f"{'variant':<13} {'seconds':>8} {'/ bare_iterate':>15} {'/ bare_decode':>14} {'peak RSS MB':>12}")
    for name in RUN_VARIANTS:
        m = medians[name]
        print(
            f"{name:<13} {m:8.3f} {m / medians['bare_iterate']:14.2f}x {m / medians['bare_decode']:13.2f}x "
            f"{peaks[name]:12.0f}"
        )
    print(f"open_log / bare_iterate: {medians['open_log'] / medians['bare_iterate']:.2f}x (target <= 1.5x)")


def _columns_append(columns: dict[str, list], data: bytes) -> None:
    for key, value in json.loads(data).items():
        columns.setdefault(key, []).append(value)


def run_variant(name: str, path: Path) -> dict[str, float]:
    start = time.perf_counter()
    if name == "bare_stream":
        from mcap.records import Message
        from mcap.stream_reader import StreamReader

        columns: dict[str, list] = {}
        log_times: list[int] = []
        with open(path, "rb") as f:
            for record in StreamReader(f).records:
                if isinstance(record, Message):
                    log_times.append(record.log_time)
                    _columns_append(columns, record.data)
        count = len(log_times)
    elif name == "bare_indexed":
        from mcap.reader import make_reader

        columns = {}
        log_times = []
        with open(path, "rb") as f:
            for _schema, _channel, message in make_reader(f).iter_messages():
                log_times.append(message.log_time)
                _columns_append(columns, message.data)
        count = len(log_times)
    elif name == "read_run":
        from rig.log.reading.reader import read_run

        frame = read_run(path).topic("/rig/loadcell")
        count = len(frame)
    else:
        raise SystemExit(f"unknown variant {name}")
    elapsed = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"seconds": elapsed, "messages": count, "peak_rss_mb": peak_mb}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--default-run", action="store_true", help="the default run's log, library variants")
    parser.add_argument(  # several names: each in turn (JSON lines), `generate` and `imports` alone
        "--variant",
        nargs="+",
        choices=(*VARIANTS, *RUN_VARIANTS, "generate", "imports"),
        help=argparse.SUPPRESS,
    )
    parser.add_argument("--file", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.messages, args.repeats = 2_000, 1
    if args.variant == ["generate"]:
        generate(args.file, args.messages)
        return
    if args.variant == ["imports"]:
        import mcap.reader  # noqa: F401
        import pandas  # noqa: F401
        import pyarrow.json  # noqa: F401

        import rig.log.reading.reader  # noqa: F401

        print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
        return
    if args.variant:  # child process: its variants in turn, a JSON line each on stdout
        for name in args.variant:
            run = run_library_variant if name in RUN_VARIANTS else run_variant
            print(json.dumps(run(name, args.file)), flush=True)
        return
    if args.default_run:
        default_run_main(args.repeats)
        return
    if args.smoke:
        default_run_main(args.repeats, smoke=True)

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        start = time.perf_counter()
        child = [sys.executable, __file__, "--file", str(path), "--messages", str(args.messages)]
        subprocess.run([*child, "--variant", "generate"], check=True, timeout=900)
        size_mb = path.stat().st_size / 1e6
        print(f"generated {args.messages} messages, {size_mb:.1f} MB in {time.perf_counter() - start:.1f} s")
        imports = subprocess.run(
            [*child, "--variant", "imports"], capture_output=True, text=True, check=True, timeout=120
        )
        import_mb = float(imports.stdout)
        print(f"peak RSS of a child that only imports mcap, pandas, pyarrow, rig.log: {import_mb:.0f} MB")
        best: dict[str, dict[str, float]] = {}
        for _ in range(args.repeats):
            for name, result in variant_results(VARIANTS, child, args.smoke).items():
                if result["messages"] != args.messages:
                    raise SystemExit(f"{name} read {result['messages']} messages, expected {args.messages}")
                if name not in best or result["seconds"] < best[name]["seconds"]:
                    best[name] = {
                        **result,
                        "peak_rss_mb": max(result["peak_rss_mb"], best.get(name, result)["peak_rss_mb"]),
                    }
    print(f"best of {args.repeats}; peak RSS is the largest seen")
    print(f"{'variant':<13} {'seconds':>8} {'msg/s':>9} {'peak RSS MB':>12}")
    for name, r in best.items():
        print(f"{name:<13} {r['seconds']:8.2f} {r['messages'] / r['seconds']:9.0f} {r['peak_rss_mb']:12.0f}")
    ratio = best["read_run"]["seconds"] / best["bare_stream"]["seconds"]
    print(f"ratio read_run / bare_stream time: {ratio:.2f}x (target <= 1.5x)")


if __name__ == "__main__":
    main()
