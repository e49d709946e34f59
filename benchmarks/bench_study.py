"""Wall time of `rig study` against N sequential byte-level `rig run`s, measured side by side.

For N seeds, each repetition times, in an order rotated per repetition:

* baseline: N sequential `rig run PROTOCOL --seed S --json` processes (byte-level devices, MCAP log);
* `rig study PROTOCOL --seeds 0-(N-1) --jobs 2 --devices byte`;
* `rig study PROTOCOL --seeds 0-(N-1) --jobs 2 --devices object`.

Every measurement is a whole command as a user runs it (interpreter start and imports included).
Prints each repetition and the medians of the two ratios. Targets: byte study <= 0.6x, object
study <= 0.1x of the baseline. The default N is 24 seeds (a study's fixed start-up, about one
run's time, is then amortised as in real use; at 6 seeds it weighed as much as the runs).

`--profile SEED` instead runs that seed in this process on object-level devices
(`rig.study.worker.run_seed`, after one warm-up run), prints its wall time without the profiler,
then the cProfile of a second run (cumulative, the top 30 entries).

`--baseline-tree DIR` adds, in every repetition, the object-level study of another checkout (the
same protocol file, that tree's code), so an improvement is measured side by side too.

`--dask N` instead compares the Dask path with the local pool at N workers: a local Dask cluster
of N single-threaded worker processes is started first (outside the timing, with one warm-up
study on it, as a lab's cluster would be up before a study), then every repetition times, in an
order alternated per repetition, `rig study PROTOCOL --seeds ... --jobs N` and `rig study PROTOCOL
--seeds ... --scheduler ADDRESS` (object-level devices, whole commands). Prints each repetition's
runs/s, the ratio of the Dask throughput to the local pool's and the load average, then the median
ratio (target >= 0.95). Before the repetitions it measures the Dask path's own overhead apart from
the runs (`dask_overhead`): importing `distributed` in the client, connecting, registering the
plugin, and one round trip of the study's chunks through tasks that return records without running
anything (submission, serialization, scheduling and gathering), with the pickled sizes of what goes
out per task and comes back per seed. With `--baseline-tree` the other tree's `--scheduler` study is timed too
(its client, so its way of sending the seeds, on the same workers). The default N of seeds is 64
in this mode.

    .venv/bin/python benchmarks/bench_study.py [--seeds N] [--repeats R] [--protocol PATH]
        [--baseline-tree DIR]
    .venv/bin/python benchmarks/bench_study.py --profile 3
    .venv/bin/python benchmarks/bench_study.py --dask 2 [--seeds 64] [--repeats 5] [--baseline-tree DIR]
    .venv/bin/python benchmarks/bench_study.py --smoke   (both comparisons: 1 seed of a one-trial copy
        of the protocol, once; the Dask one on 1 worker, without its warm-up study)
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from smoke_mode import SMOKE_HELP, short_protocol  # benchmarks/ is the script's directory

ROOT = Path(__file__).resolve().parent.parent


def timed(command: list[str], tree: Path = ROOT) -> float:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (str(tree), os.environ.get("PYTHONPATH")) if p),
    }
    start = time.perf_counter()
    # From the tree itself: `python -m` puts the working directory ahead of PYTHONPATH.
    subprocess.run(
        command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=tree
    )
    return time.perf_counter() - start


def sequential_runs(protocol: Path, seeds: int) -> float:
    total = 0.0
    with tempfile.TemporaryDirectory() as out:
        for seed in range(seeds):
            total += timed(
                [sys.executable, "-m", "rig.cli", "run", str(protocol), "--seed", str(seed), "--out", out]
            )
    return total


def study(protocol: Path, seeds: int, devices: str, tree: Path = ROOT, where: tuple[str, ...] = ()) -> float:
    """Wall time of one `rig study` command; `where` is how it runs the seeds (default --jobs 2)."""
    command = [sys.executable, "-m", "rig.cli", "study", str(protocol), "--seeds", f"0-{seeds - 1}"]
    return timed([*command, *(where or ("--jobs", "2")), "--devices", devices, "--json"], tree)


def dask_against_pool(
    protocol: Path, seeds: int, workers: int, repeats: int, baseline: Path | None, *, warm_up: bool = True
) -> None:
    """`--dask N`: see the module docstring (`warm_up=False`, for the smoke mode: no warm-up study)."""
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        scheduler = ("--scheduler", cluster.scheduler_address)
        measures = {
            "pool": lambda: study(protocol, seeds, "object", where=("--jobs", str(workers))),
            "dask": lambda: study(protocol, seeds, "object", where=scheduler),
        }
        if baseline is not None:
            measures["dask_baseline"] = lambda: study(protocol, seeds, "object", baseline, scheduler)
        if warm_up:  # the workers import the rig
            study(protocol, workers, "object", where=scheduler)
        dask_overhead(cluster.scheduler_address, protocol, seeds)
        names = list(measures)
        ratios: dict[str, list[float]] = {name: [] for name in names if name != "pool"}
        print(
            f"{seeds} seeds of {protocol.name}: --jobs {workers} against a local Dask cluster of {workers} "
            f"single-threaded workers, {repeats} repetitions, cpus={os.cpu_count()}"
        )
        for rep in range(repeats):
            order = names[rep % len(names) :] + names[: rep % len(names)]
            load_before = os.getloadavg()[0]
            wall = {name: measures[name]() for name in order}
            for name in ratios:
                ratios[name].append(wall["pool"] / wall[name])  # throughput ratio: runs/s over runs/s
            print(
                f"rep {rep + 1} ({' then '.join(order)}): "
                + ", ".join(f"{name} {wall[name]:.1f} s ({seeds / wall[name]:.2f} runs/s)" for name in names)
                + "; "
                + ", ".join(f"{name}/pool {ratios[name][-1]:.3f}x" for name in ratios)
                + f"; load average {load_before:.1f} -> {os.getloadavg()[0]:.1f}",
                flush=True,
            )
        print(
            "median throughput ratio: "
            + ", ".join(f"{name}/pool {statistics.median(ratios[name]):.3f}x" for name in ratios)
            + " (target >= 0.95 for dask/pool)"
        )


def _records_unrun(record: Any, seeds: list[int]) -> list[Any]:
    """A stand-in for `run_chunk`: a chunk's records, copies of one real record, without running anything."""
    import dataclasses

    return [dataclasses.replace(record, seed=seed) for seed in seeds]


def dask_overhead(address: str, protocol: Path, seeds: int) -> None:
    """What the Dask path costs besides the runs; see the module docstring. Prints one line."""
    import pickle

    from distributed import Client, as_completed

    sys.path.insert(0, str(ROOT))
    from rig.study.dask_plugin import PRELOAD_PLUGIN, PreloadRig
    from rig.study.executor import run_chunk, seed_chunks
    from rig.study.worker import StudySpec, run_seed

    bare_s = timed([sys.executable, "-c", "pass"])
    import_s = timed([sys.executable, "-c", "import distributed"]) - bare_s
    spec = StudySpec(str(protocol), None, "object")
    record = run_seed(spec, 0)  # a real record, for the size of what comes back
    start = time.perf_counter()
    with Client(address, timeout="10s") as client:
        connect_s = time.perf_counter() - start
        start = time.perf_counter()
        client.register_plugin(PreloadRig(), name=PRELOAD_PLUGIN)
        plugin_s = time.perf_counter() - start
        chunks = seed_chunks(range(seeds), sum(client.nthreads().values()))
        start = time.perf_counter()
        futures = client.map(_records_unrun, [record] * len(chunks), chunks, pure=False)
        returned = sum(len(future.result()) for future in as_completed(futures))
        round_trip_s = time.perf_counter() - start
    assert returned == seeds
    task_bytes = len(pickle.dumps((run_chunk, spec, chunks[0])))
    print(
        f"dask overhead: import distributed {import_s * 1e3:.0f} ms, connect {connect_s * 1e3:.0f} ms, "
        f"plugin {plugin_s * 1e3:.0f} ms, {len(chunks)} chunk tasks round trip without runs "
        f"{round_trip_s * 1e3:.0f} ms ({round_trip_s / len(chunks) * 1e3:.1f} ms per task); pickled: "
        f"a task's arguments {task_bytes} B, a record {len(pickle.dumps(record))} B",
        flush=True,
    )


def profile_seed(protocol: Path, seed: int) -> None:
    import cProfile
    import pstats

    sys.path.insert(0, str(ROOT))
    from rig.study.worker import StudySpec, run_seed

    spec = StudySpec(str(protocol), None, "object")
    run_seed(spec, seed + 1)  # warm-up: first-use imports and caches
    start = time.perf_counter()
    record = run_seed(spec, seed)
    wall_s = time.perf_counter() - start
    print(f"seed {seed}, object-level, in process: {wall_s:.3f} s wall ({record.status})")
    profiler = cProfile.Profile()
    profiler.enable()
    run_seed(spec, seed)
    profiler.disable()
    pstats.Stats(profiler).sort_stats("cumulative").print_stats(30)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--protocol", type=Path, default=ROOT / "protocols" / "joint_estimation.yaml")
    parser.add_argument(
        "--seeds", type=int, default=None, help="seeds per measurement (default 24; 64 with --dask)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="repetitions (default 3)")
    parser.add_argument("--profile", type=int, metavar="SEED", help="profile one object-level run instead")
    parser.add_argument(
        "--baseline-tree",
        type=Path,
        help="also time the object-level study of another checkout (e.g. ../main) in every repetition",
    )
    parser.add_argument(
        "--dask",
        type=int,
        metavar="N",
        help="compare --scheduler on a local cluster of N workers with --jobs N",
    )
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        with tempfile.TemporaryDirectory() as folder:
            args.protocol = short_protocol(Path(folder), args.protocol, trials=1)
            args.seeds, args.repeats = 1, 1
            studies_against_runs(args)
            dask_against_pool(args.protocol, 1, 1, 1, None, warm_up=False)
        return
    if args.profile is not None:
        profile_seed(args.protocol, args.profile)
        return
    if args.dask is not None:
        baseline = None if args.baseline_tree is None else args.baseline_tree.resolve()
        dask_against_pool(args.protocol, args.seeds or 64, args.dask, args.repeats, baseline)
        return
    args.seeds = args.seeds or 24
    studies_against_runs(args)


def studies_against_runs(args: argparse.Namespace) -> None:
    """The default comparison: N sequential runs, the byte-level and the object-level study."""
    measures = {
        "runs": lambda: sequential_runs(args.protocol, args.seeds),
        "study_byte": lambda: study(args.protocol, args.seeds, "byte"),
        "study_object": lambda: study(args.protocol, args.seeds, "object"),
    }
    ratios: dict[str, list[float]] = {"study_byte": [], "study_object": []}
    if args.baseline_tree is not None:
        tree = args.baseline_tree.resolve()
        measures["study_object_baseline"] = lambda: study(args.protocol, args.seeds, "object", tree)
        ratios["study_object_baseline"] = []
    names = list(measures)
    print(f"{args.seeds} seeds of {args.protocol.name}, {args.repeats} repetitions, cpus={os.cpu_count()}")
    for rep in range(args.repeats):
        order = names[rep % len(names) :] + names[: rep % len(names)]
        wall = {name: measures[name]() for name in order}
        for name in ratios:
            ratios[name].append(wall[name] / wall["runs"])
        byte, obj = wall["study_byte"], wall["study_object"]
        print(
            f"rep {rep + 1}: {args.seeds} x rig run {wall['runs']:.1f} s; study --jobs 2 byte "
            f"{byte:.1f} s ({ratios['study_byte'][-1]:.3f}x), object {obj:.1f} s "
            f"({ratios['study_object'][-1]:.3f}x)"
            + (
                f"; baseline tree's object study {wall['study_object_baseline']:.1f} s "
                f"({ratios['study_object_baseline'][-1]:.3f}x)"
                if "study_object_baseline" in wall
                else ""
            ),
            flush=True,
        )
    print(
        f"median ratio: byte-level study {statistics.median(ratios['study_byte']):.3f}x (target <= 0.6), "
        f"object-level study {statistics.median(ratios['study_object']):.3f}x (target <= 0.1)"
        + (
            f"; baseline tree's object-level study {statistics.median(ratios['study_object_baseline']):.3f}x"
            if ratios.get("study_object_baseline")
            else ""
        )
    )


if __name__ == "__main__":
    main()
