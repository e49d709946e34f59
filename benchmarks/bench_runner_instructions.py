"""Instructions per `rig run` of two trees, counted by valgrind (callgrind): a speed ratio without noise.

Wall and CPU times of `bench_runner.py` vary by ±10 % between rounds on a loaded shared machine;
an instruction count does not. For each tree this counts the whole process twice under callgrind,
once with one run of PROTOCOL and once with three (seeds 0, 1, 0), in the same process and
interpreter; half the difference is the instructions of one run without start-up and imports.
Prints both counts and their ratio (baseline / this tree: above 1 means this tree does less).

    .venv/bin/python benchmarks/bench_runner_instructions.py --baseline-tree ../main [--protocol PATH]
    .venv/bin/python benchmarks/bench_runner_instructions.py --smoke

The interpreter of a tree is its own `.venv/bin/python`, or this one's where it has none.

`--smoke` cannot afford callgrind on a run: the imports alone take about 40 s under it. It runs the
counted program of this tree once as it is, without valgrind (one run of a one-trial protocol),
then counts under callgrind the same program with no run (no import of the rig either), which
checks the valgrind call and the parsing of its count.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from smoke_mode import SMOKE_HELP, short_protocol, tree_python  # benchmarks/ is the script's directory

ROOT = Path(__file__).resolve().parent.parent
RUNS = """
import sys, tempfile
from pathlib import Path
sys.path.insert(0, '.')
runs = int(sys.argv[2])
if runs:
    from benchmarks.bench_runner import one_run
with tempfile.TemporaryDirectory() as tmp:
    for k in range(runs):
        one_run(Path(sys.argv[1]), k % 2, Path(tmp) / str(k))
"""


def instructions(tree: Path, protocol: Path, runs: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        command = [
            "valgrind",
            "--tool=callgrind",
            f"--callgrind-out-file={out}",
            tree_python(tree),
            "-c",
            RUNS,
        ]
        result = subprocess.run(
            [*command, str(protocol), str(runs)],
            cwd=tree,
            capture_output=True,
            text=True,
            check=True,
        )
    match = re.search(r"Collected : (\d+)", result.stderr)
    if match is None:
        sys.exit(f"no instruction count from valgrind:\n{result.stderr[-2000:]}")
    return int(match.group(1))


def smoke(protocol: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        short = short_protocol(Path(tmp), (ROOT / protocol).resolve(), trials=1)
        subprocess.run(
            [tree_python(ROOT), "-c", RUNS, str(short), "1"], cwd=ROOT, check=True, capture_output=True
        )
        print(f"this tree: one run of {short.name} without valgrind")
        print(f"this tree: {instructions(ROOT, short, 0):,} instructions with no run, under callgrind")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-tree", type=Path, help="required but with --smoke")
    parser.add_argument("--protocol", type=Path, default=Path("protocols/smoke.yaml"))
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP + " (see above)")
    args = parser.parse_args()
    if args.smoke:
        smoke(args.protocol)
        return
    if args.baseline_tree is None:
        parser.error("--baseline-tree is required")
    per_run = {}
    for name, tree in (("baseline", args.baseline_tree.resolve()), ("this tree", ROOT)):
        one, three = instructions(tree, args.protocol, 1), instructions(tree, args.protocol, 3)
        per_run[name] = (three - one) / 2
        print(f"{name}: {one:,} instructions with 1 run, {three:,} with 3: {per_run[name]:,.0f} per run")
    print(f"ratio baseline / this tree: {per_run['baseline'] / per_run['this tree']:.4f}")


if __name__ == "__main__":
    main()
