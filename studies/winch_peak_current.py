"""How close the simulated winch comes to its current limit: peak current and tension per run.

The rig config's `limits.winch_current_limit_a` is the winch's hardware tension cap. Lowering it
(so that its stall tension is at most 1.25 x the force ceiling) must not change a run that never
reaches it. For each protocol and rig config this runs `rig run` on the simulated rig and prints
the highest |Present Current| the winch reported (`/rig/servo/state`), the highest tension the
load cell logged, and the rig's current limit with the share of it reached.

    python studies/winch_peak_current.py [--seeds 0 1] [--rigs default protocols/rigs/scenarios/*.yaml]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]
PROTOCOLS = ("joint_estimation", "link_validation", "smoke", "joint_estimation_adaptive")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--rigs", nargs="+", default=["default"])
    args = parser.parse_args()
    print("| protocol | rig | seed | exit | peak winch current | current limit | share | peak tension |")
    print("|---|---|---|---|---|---|---|---|")
    for name in PROTOCOLS:
        for rig in args.rigs:
            config_path = None if rig == "default" else Path(rig)
            limit_a = load_rig_config(config_path).limits.winch_current_limit_a
            for seed in args.seeds:
                with tempfile.TemporaryDirectory() as out:
                    protocol = ROOT / "protocols" / f"{name}.yaml"
                    request = RunRequest(protocol, config_path, Path(out), seed, run_id="peak")
                    prepared = prepare_run(request)
                    sim = open_simulated_rig(prepared)
                    report = execute_run(prepared, sim, SilentProgress())
                    log = read_run(Path(out))
                    states = log.topic("/rig/servo/state")
                    peak_a = float(states[states.role == "winch"].current_a.abs().max())
                    peak_n = float(log.topic("/rig/loadcell").force_n.max())
                print(
                    f"| {name} | {Path(rig).stem} | {seed} | {int(report.exit_code)} | {peak_a:.3f} A "
                    f"| {limit_a:.3f} A | {100 * peak_a / limit_a:.0f} % | {peak_n:.1f} N |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
