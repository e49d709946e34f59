"""A behaviour snapshot of a tree: every shipped protocol on every shipped rig, normalised, to diff.

Runs `rig run PROTOCOL [--rig CONFIG] --seed S --json` for the four shipped protocols on the default
simulated rig, every scenario and every fault config, seeds 0 and 1, and `rig replay --json` of the
logs of the default rig's runs, and writes one normalised JSON file per run (run ids, log paths,
wall times, the tree's own path and temporary directories removed) and its exit code. Two snapshots
of the same behaviour are byte-identical, so a refactoring that must not change behaviour is
checked with `diff -r`:

    python studies/behaviour_snapshot.py --out /tmp/snap-old   # in the old tree
    python studies/behaviour_snapshot.py --out /tmp/snap-new   # in the new tree
    diff -r /tmp/snap-old /tmp/snap-new
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PROTOCOLS = ("joint_estimation", "link_validation", "smoke", "joint_estimation_adaptive")
_DROPPED_KEYS = {"run_id", "log", "logs", "path"}
_TEMP_PATH = re.compile(r"/tmp/[^\s'\"]+")
_RUN_STAMP = re.compile(r"\b\d{8}T\d{6}-")  # the start time in a default run id (and its file names)


def _scrub(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _scrub(v) for k, v in value.items() if k not in _DROPPED_KEYS and not k.endswith("wall_s")}
    if isinstance(value, list):
        return [_scrub(v) for v in value]
    if isinstance(value, str):
        return _RUN_STAMP.sub("STAMP-", _TEMP_PATH.sub("TMP", value.replace(str(ROOT), "ROOT")))
    return value


def _normalised(stdout: str) -> str:
    try:
        data = json.loads(stdout)
    except json.JSONDecodeError:
        return _TEMP_PATH.sub("TMP", stdout.replace(str(ROOT), "ROOT"))
    return json.dumps(_scrub(data), indent=1, sort_keys=True) + "\n"


def _rig(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "rig.cli", *args], cwd=ROOT, capture_output=True, text=True, check=False
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, required=True, help="directory for the snapshot (created)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="seeds per run (default 0 1)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rigs: list[tuple[str, list[str]]] = [("default", [])]
    for folder in ("scenarios", "faults"):
        for config in sorted((ROOT / "protocols" / "rigs" / folder).glob("*.yaml")):
            rigs.append((config.stem, ["--rig", str(config)]))
    for protocol in PROTOCOLS:
        for rig_name, rig_args in rigs:
            for seed in args.seeds:
                name = f"{protocol}.{rig_name}.{seed}"
                with tempfile.TemporaryDirectory() as tmp:
                    done = _rig(
                        "run",
                        f"protocols/{protocol}.yaml",
                        *rig_args,
                        "--seed",
                        str(seed),
                        "--json",
                        "--out",
                        tmp,
                    )
                    logs = sorted(Path(tmp).glob("*.mcap")) if rig_name == "default" else []
                    replayed = [_rig("replay", str(log), "--json") for log in logs]
                (args.out / f"{name}.json").write_text(_normalised(done.stdout))
                (args.out / f"{name}.rc").write_text(f"{done.returncode}\n")
                print(f"{name}: exit {done.returncode}", file=sys.stderr)
                for part, replay in enumerate(replayed):
                    (args.out / f"replay.{name}.{part}.json").write_text(_normalised(replay.stdout))
                    (args.out / f"replay.{name}.{part}.rc").write_text(f"{replay.returncode}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
