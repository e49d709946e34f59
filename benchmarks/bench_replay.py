"""`rig replay` of a short and a 10x longer run: peak memory and time, this tree beside an old one.

Generates two logs with this tree's `rig run` on the simulated rig (object devices, seed 0):
`protocols/joint_estimation.yaml` as shipped (8 distances x 3 repeats = 24 trials, about 99,000
load-cell samples) and the same protocol with `--scale` times the repeats (240 trials by default).
Then runs `rig replay LOG --json` and `rig replay LOG --json --report DIR` on both logs, each in its
own process, with this tree and (with `--base`) an old tree alternately, and reads each process's
peak RSS from `os.wait4` (its own ru_maxrss; the parent imports nothing but the standard library, so
no child starts from a large high-water mark). The logs live in a temporary directory and are
deleted at the end.

Printed per tree and mode: peak RSS and wall time of the short and the long log (medians over
`--repeats`), their ratios long / short (the memory target: within 1.2; time: linear in the log,
so at most the scale), and the ratios new / old.

Run: .venv/bin/python benchmarks/bench_replay.py [--base /path/to/old/tree] [--scale 10] [--repeats 1]
     [--smoke]
(--smoke: one log of a one-trial protocol serves as both, each mode replayed once per tree.
--base: a checkout of an older commit, e.g. the tree before bounded replay, run with its own .venv's
interpreter or, without one, this one's.)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from smoke_mode import SMOKE_HELP, short_protocol, tree_python  # benchmarks/ is the script's directory

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "protocols" / "joint_estimation.yaml"
SHIPPED_REPEATS = "    repeats: 3\n"
MODES = ("json", "report")


def generate(out: Path, repeats: int, source: Path = SHIPPED, repeats_line: str = SHIPPED_REPEATS) -> Path:
    """A log of joint_estimation (`source`) with `repeats` repeats per distance, by this tree's `rig run`.

    `repeats_line`: the one line of `source` that sets its repeats, replaced.
    """
    text = source.read_text()
    if text.count(repeats_line) != 1:
        raise SystemExit(f"{source}: expected one {repeats_line.strip()!r} line to scale")
    protocol = out / f"joint_estimation_x{repeats}.yaml"
    protocol.write_text(text.replace(repeats_line, repeats_line.split(":")[0] + f": {repeats}\n"))
    run_id = f"bench{repeats}"
    command = [tree_python(ROOT), "-m", "rig.cli", "run", str(protocol), "--out", str(out)]
    command += ["--run-id", run_id, "--devices", "object", "--seed", "0", "--json"]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"rig run failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    return out / f"{run_id}.mcap"


def measure(tree: Path, log: Path, mode: str, scratch: Path) -> tuple[float, float]:
    """(peak RSS in MB, wall seconds) of one `rig replay` process of `tree`."""
    command = [tree_python(tree), "-m", "rig.cli", "replay", str(log), "--json"]
    if mode == "report":
        command += ["--report", tempfile.mkdtemp(prefix="report.", dir=scratch) + "/r"]
    start = time.perf_counter()
    with open(os.devnull, "wb") as sink:
        child = subprocess.Popen(command, cwd=tree, stdout=sink, stderr=subprocess.PIPE)
        assert child.stderr is not None
        errors = child.stderr.read()
        _pid, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"{' '.join(command)}: exit {child.returncode}: {errors.decode()[-500:]}")
    return usage.ru_maxrss / 1024, seconds


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--base", type=Path, help="an older tree to run alternately (its .venv, if any)")
    parser.add_argument("--scale", type=int, default=10, help="the long log has this many times the trials")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each (tree, log, mode)")
    parser.add_argument("--json", action="store_true", help="print the results as one JSON object")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    trees = {"new": ROOT}
    if args.base is not None:
        if not (args.base / "rig" / "cli").is_dir():
            raise SystemExit(f"--base {args.base}: not a checkout of this project (no rig/cli)")
        trees = {"old": args.base.resolve(), "new": ROOT}
    with tempfile.TemporaryDirectory(prefix="bench_replay.") as tmp:
        scratch = Path(tmp)
        if args.smoke:  # one log of a one-trial copy of the protocol, as the short and the long one
            args.scale, args.repeats = 1, 1
            source = short_protocol(scratch, SHIPPED, "source.yaml", trials=1)
            log = generate(scratch, 1, source, "  repeats: 1\n")
            logs = {"short": log, "long": log}
        else:
            logs = {"short": generate(scratch, 3), "long": generate(scratch, 3 * args.scale)}
        sizes = {name: log.stat().st_size for name, log in logs.items()}
        samples: dict[tuple[str, str, str], list[tuple[float, float]]] = {}
        for _ in range(args.repeats):
            for mode in MODES:
                measured: dict[tuple[str, Path], tuple[float, float]] = {}  # smoke: one log, two names
                for log_name, log in logs.items():
                    for tree_name, tree in trees.items():  # alternately, so load changes hit both
                        if (tree_name, log) not in measured:
                            measured[(tree_name, log)] = measure(tree, log, mode, scratch)
                        samples.setdefault((tree_name, mode, log_name), []).append(measured[(tree_name, log)])
    medians = {
        key: (statistics.median(r for r, _ in runs), statistics.median(s for _, s in runs))
        for key, runs in samples.items()
    }
    report: dict[str, object] = {"log_bytes": sizes, "scale": args.scale, "repeats": args.repeats, "runs": []}
    rows = []
    for tree_name in trees:
        for mode in MODES:
            short_mb, short_s = medians[(tree_name, mode, "short")]
            long_mb, long_s = medians[(tree_name, mode, "long")]
            row = {
                "tree": tree_name,
                "mode": mode,
                "short_peak_mb": round(short_mb, 1),
                "long_peak_mb": round(long_mb, 1),
                "peak_ratio_long_short": round(long_mb / short_mb, 3),
                "short_s": round(short_s, 2),
                "long_s": round(long_s, 2),
                "time_ratio_long_short": round(long_s / short_s, 2),
            }
            rows.append(row)
    report["runs"] = rows
    ratios: dict[str, dict[str, float]] = {}
    if "old" in trees:
        for mode in MODES:
            for log_name in ("short", "long"):
                (new_mb, new_s), (old_mb, old_s) = (medians[(t, mode, log_name)] for t in ("new", "old"))
                ratio = {"peak": round(new_mb / old_mb, 3), "time": round(new_s / old_s, 3)}
                ratios[f"{mode} {log_name}"] = ratio
        report["new_over_old"] = ratios
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    print(
        f"logs: short {sizes['short'] / 1e6:.1f} MB, long {sizes['long'] / 1e6:.1f} MB (x{args.scale} trials)"
    )
    header = ("tree", "mode", "short MB", "long MB", "long/short", "short s", "long s", "long/short")
    print("{:5} {:7} {:>9} {:>8} {:>10} {:>8} {:>7} {:>10}".format(*header))
    for row in rows:
        print(
            f"{row['tree']:5} {row['mode']:7} {row['short_peak_mb']:9.1f} {row['long_peak_mb']:8.1f} "
            f"{row['peak_ratio_long_short']:10.3f} {row['short_s']:8.2f} {row['long_s']:7.2f} "
            f"{row['time_ratio_long_short']:10.2f}"
        )
    for key, ratio in ratios.items():
        print(f"new / old, {key}: peak RSS {ratio['peak']:.3f}x, time {ratio['time']:.3f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
