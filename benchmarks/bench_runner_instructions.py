"""Instructions per `rig run` of two trees, counted by valgrind (callgrind): a speed ratio without noise.

Wall and CPU times of `bench_runner.py` vary by ±10 % between rounds on a loaded shared machine;
an instruction count does not. For each tree this counts the whole process twice under callgrind,
once with one run of PROTOCOL and once with three (seeds 0, 1, 0), in the same process and
interpreter; half the difference is the instructions of one run without start-up and imports.
Prints both counts and their ratio (baseline / this tree: above 1 means this tree does less).

    .venv/bin/python benchmarks/bench_runner_instructions.py --baseline-tree ../main [--protocol PATH]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RUNS = """
import sys, tempfile
from pathlib import Path
sys.path.insert(0, '.')
from benchmarks.bench_runner import one_run
with tempfile.TemporaryDirectory() as tmp:
    for k in range(int(sys.argv[2])):
        one_run(Path(sys.argv[1]), k % 2, Path(tmp) / str(k))
"""


def instructions(tree: Path, protocol: Path, runs: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        python = str(tree / ".venv" / "bin" / "python")
        command = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", python, "-c", RUNS]
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-tree", type=Path, required=True)
    parser.add_argument("--protocol", type=Path, default=Path("protocols/smoke.yaml"))
    args = parser.parse_args()
    per_run = {}
    for name, tree in (("baseline", args.baseline_tree.resolve()), ("this tree", ROOT)):
        one, three = instructions(tree, args.protocol, 1), instructions(tree, args.protocol, 3)
        per_run[name] = (three - one) / 2
        print(f"{name}: {one:,} instructions with 1 run, {three:,} with 3: {per_run[name]:,.0f} per run")
    print(f"ratio baseline / this tree: {per_run['baseline'] / per_run['this tree']:.4f}")


if __name__ == "__main__":
    main()
