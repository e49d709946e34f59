"""How long the line stays loaded after a slip: from the detection to the cell reading it slack.

After a slip the runner holds `ramp.hold_after_slip_s`, then releases the line before anything
slow (docs/design.md §6 2e) and logs the time on `/rig/log` ("line released after the slip in
… s"). This runs each shipped protocol on the simulated rig (and, with `--rigs`, other simulated
rig configs) for the given seeds and prints, per protocol and rig, how many slips and the
shortest, median and longest time loaded, against `limits.max_loaded_after_slip_s`.

    python studies/loaded_after_slip.py [--seeds 0 1] [--rigs default protocols/rigs/forks-link1.yaml]
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
from pathlib import Path

from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]
PROTOCOLS = ("joint_estimation", "link_validation", "smoke")
_LOADED = re.compile(r"line released after the slip in ([0-9.]+) s")


def loaded_times_s(protocol: Path, rig: Path | None, seed: int) -> list[float]:
    """The logged time loaded after each slip of one run."""
    with tempfile.TemporaryDirectory() as out:
        prepared = prepare_run(RunRequest(protocol, rig, Path(out), seed=seed, run_id="loaded"))
        execute_run(prepared, open_simulated_rig(prepared), SilentProgress())
        notes = read_run(Path(out)).topic("/rig/log").message
        return [float(m.group(1)) for m in map(_LOADED.search, notes) if m]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--rigs", nargs="+", default=["default"])
    args = parser.parse_args()
    print("| protocol | rig | slips | shortest | median | longest | bound |")
    print("|---|---|---|---|---|---|---|")
    for rig_name in args.rigs:
        rig = None if rig_name == "default" else Path(rig_name)
        bound_s = load_rig_config(rig).limits.max_loaded_after_slip_s
        for name in PROTOCOLS:
            times = [
                t
                for seed in args.seeds
                for t in loaded_times_s(ROOT / "protocols" / f"{name}.yaml", rig, seed)
            ]
            median_s = statistics.median(times)
            print(
                f"| {name} | {rig_name} | {len(times)} | {min(times):.3f} s | {median_s:.3f} s "
                f"| {max(times):.3f} s | {bound_s:g} s |"
            )


if __name__ == "__main__":
    main()
