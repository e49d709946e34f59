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

    .venv/bin/python benchmarks/bench_study.py [--seeds N] [--repeats R] [--protocol PATH]
        [--baseline-tree DIR]
    .venv/bin/python benchmarks/bench_study.py --profile 3
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


def study(protocol: Path, seeds: int, devices: str, tree: Path = ROOT) -> float:
    command = [sys.executable, "-m", "rig.cli", "study", str(protocol), "--seeds", f"0-{seeds - 1}"]
    return timed([*command, "--jobs", "2", "--devices", devices, "--json"], tree)


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
    parser.add_argument("--seeds", type=int, default=24, help="seeds per measurement (default 24)")
    parser.add_argument("--repeats", type=int, default=3, help="repetitions (default 3)")
    parser.add_argument("--profile", type=int, metavar="SEED", help="profile one object-level run instead")
    parser.add_argument(
        "--baseline-tree",
        type=Path,
        help="also time the object-level study of another checkout (e.g. ../main) in every repetition",
    )
    args = parser.parse_args()
    if args.profile is not None:
        profile_seed(args.protocol, args.profile)
        return
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
