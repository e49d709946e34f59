"""Wall time of `rig study` against N sequential byte-level `rig run`s, measured side by side.

For N seeds, each repetition times, in an order rotated per repetition:

* baseline: N sequential `rig run PROTOCOL --seed S --json` processes (byte-level devices, MCAP log);
* `rig study PROTOCOL --seeds 0-(N-1) --jobs 2 --devices byte`;
* `rig study PROTOCOL --seeds 0-(N-1) --jobs 2 --devices object`.

Every measurement is a whole command as a user runs it (interpreter start and imports included).
Prints each repetition and the medians of the two ratios. Targets: byte study <= 0.6x, object
study <= 0.1x of the baseline.

    .venv/bin/python benchmarks/bench_study.py [--seeds N] [--repeats R] [--protocol PATH]
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


def timed(command: list[str]) -> float:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p),
    }
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    return time.perf_counter() - start


def sequential_runs(protocol: Path, seeds: int) -> float:
    total = 0.0
    with tempfile.TemporaryDirectory() as out:
        for seed in range(seeds):
            total += timed(
                [sys.executable, "-m", "rig.cli", "run", str(protocol), "--seed", str(seed), "--out", out]
            )
    return total


def study(protocol: Path, seeds: int, devices: str) -> float:
    command = [sys.executable, "-m", "rig.cli", "study", str(protocol), "--seeds", f"0-{seeds - 1}"]
    return timed([*command, "--jobs", "2", "--devices", devices, "--json"])


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--protocol", type=Path, default=ROOT / "protocols" / "joint_estimation.yaml")
    parser.add_argument("--seeds", type=int, default=6, help="seeds per measurement (default 6)")
    parser.add_argument("--repeats", type=int, default=3, help="repetitions (default 3)")
    args = parser.parse_args()
    measures = {
        "runs": lambda: sequential_runs(args.protocol, args.seeds),
        "study_byte": lambda: study(args.protocol, args.seeds, "byte"),
        "study_object": lambda: study(args.protocol, args.seeds, "object"),
    }
    names = list(measures)
    ratios: dict[str, list[float]] = {"study_byte": [], "study_object": []}
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
            f"({ratios['study_object'][-1]:.3f}x)",
            flush=True,
        )
    print(
        f"median ratio: byte-level study {statistics.median(ratios['study_byte']):.3f}x (target <= 0.6), "
        f"object-level study {statistics.median(ratios['study_object']):.3f}x (target <= 0.1)"
    )


if __name__ == "__main__":
    main()
