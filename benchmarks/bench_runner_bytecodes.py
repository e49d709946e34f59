"""Bytecodes executed per Python function in one `rig run`, two trees side by side: where a run's cost moved.

`bench_runner_instructions.py` says by how much two trees differ (valgrind instructions of the
whole process); this says where, in Python terms, without timing noise. For each tree it runs
PROTOCOL once (seed 1, to warm up) and once more (seed 0) under `sys.settrace` with opcode events,
counting the bytecodes and calls of each function (by file and name, so a function that moved
between modules shows as one gone and one new). Work done in C (builtins, regular expressions,
numpy, pickling) is not counted, only the bytecodes that call it. About 4 minutes per tree.

    .venv/bin/python benchmarks/bench_runner_bytecodes.py --baseline-tree DIR [--protocol PATH] [--top N]
    .venv/bin/python benchmarks/bench_runner_bytecodes.py --smoke   (one trial, this tree against itself,
        without the warm-up run: its first-use imports are counted too, about 0.4 % more bytecodes)

The interpreter of a tree is its own `.venv/bin/python`, or this one's where it has none.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

from smoke_mode import SMOKE_HELP, short_protocol, tree_python  # benchmarks/ is the script's directory

ROOT = Path(__file__).resolve().parent.parent
# Run in the tree's own interpreter; prints {"file:function": bytecodes, "file:function:calls": calls}.
# Arguments: the protocol, the tree's path with a trailing slash, 1 to warm up first (0: not).
COUNT = """
import collections, json, re, sys, tempfile, threading
from pathlib import Path
sys.path.insert(0, '.')
from benchmarks.bench_runner import one_run
counts = collections.Counter()
def tracer(frame, event, arg):
    if event != 'call':
        return None
    frame.f_trace_opcodes, frame.f_trace_lines = True, False
    code = frame.f_code
    path = re.sub(r'.*site-packages/', 'site-packages/', code.co_filename.replace(sys.argv[2], ''))
    key = f'{path}:{code.co_name}'
    counts[key + ':calls'] += 1
    def local(frame, event, arg):
        if event == 'opcode':
            counts[key] += 1
        return local
    return local
with tempfile.TemporaryDirectory() as tmp:
    if sys.argv[3] == '1':
        one_run(Path(sys.argv[1]), 1, Path(tmp) / 'warm')
    threading.settrace(tracer)
    sys.settrace(tracer)
    one_run(Path(sys.argv[1]), 0, Path(tmp) / 'run')
    sys.settrace(None)
    threading.settrace(None)
print(json.dumps(counts))
"""


def bytecodes(tree: Path, protocol: Path, warm_up: bool = True) -> dict[str, int]:
    result = subprocess.run(
        [tree_python(tree), "-c", COUNT, str(protocol), f"{tree}/", "1" if warm_up else "0"],
        cwd=tree,
        capture_output=True,
        text=True,
        check=True,
    )
    counts: dict[str, int] = json.loads(result.stdout.splitlines()[-1])
    return counts


def total(counts: dict[str, int]) -> int:
    return sum(n for key, n in counts.items() if not key.endswith(":calls"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-tree", type=Path, help="required but with --smoke")
    parser.add_argument("--protocol", type=Path, default=Path("protocols/joint_estimation.yaml"))
    parser.add_argument("--top", type=int, default=25, help="functions listed each way")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP + "; this tree against itself")
    args = parser.parse_args()
    if args.baseline_tree is None and not args.smoke:
        parser.error("--baseline-tree is required")
    with tempfile.TemporaryDirectory() as tmp:
        if args.smoke:  # one trial, counted once (not warmed up) and taken as both trees'
            protocol = short_protocol(Path(tmp), (ROOT / args.protocol).resolve(), trials=1)
            old = new = bytecodes(ROOT, protocol, warm_up=False)
        else:
            old, new = bytecodes(args.baseline_tree.resolve(), args.protocol), bytecodes(ROOT, args.protocol)
    ratio = total(new) / total(old)
    print(f"bytecodes per run: baseline {total(old):,}, this tree {total(new):,}: ratio {ratio:.4f}")
    names = {key for key in old.keys() | new.keys() if not key.endswith(":calls")}
    moved = sorted(names, key=lambda key: new.get(key, 0) - old.get(key, 0))
    row = "{:>+11,} {:>11,} {:>11,}  calls {:>8,} {:>8,}  {}"
    for title, keys in (("more in this tree", moved[::-1][: args.top]), ("fewer", moved[: args.top])):
        print(f"--- {title}: change, baseline, this tree; calls baseline, this tree; function")
        for key in keys:
            before, after = old.get(key, 0), new.get(key, 0)
            calls = old.get(key + ":calls", 0), new.get(key + ":calls", 0)
            print(row.format(after - before, before, after, *calls, key))


if __name__ == "__main__":
    main()
