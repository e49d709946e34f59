"""The fault matrix as a table: each scenario of protocols/rigs/faults/ run on the simulated rig.

For every scenario config: the exit code, trials completed, whether the run reported its safe
state as verified, what the simulator's truth says a person would find (line tension, torque),
and whether anything was lost (every journalled trial must come back from `rig replay`).

    python studies/fault_matrix.py [--protocol protocols/smoke.yaml] [--seed 0]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from rig.analysis.replay_run import replay
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--protocol", type=Path, default=ROOT / "protocols" / "smoke.yaml")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    columns = ("scenario", "exit", "trials", "safe state reported", "tension at the end", "torque")
    print("| " + " | ".join(columns) + " | trials repeated | journalled, not in log |")
    print("|---|---|---|---|---|---|---|---|")
    for config in sorted((ROOT / "protocols" / "rigs" / "faults").glob("*.yaml")):
        with tempfile.TemporaryDirectory() as out:
            request = RunRequest(args.protocol, config, Path(out), args.seed, run_id=config.stem)
            prepared = prepare_run(request)
            sim = open_simulated_rig(prepared)
            report = execute_run(prepared, sim, SilentProgress())
            replayed = replay(report.logs)
            lost = len({t.trial_id for t in report.trials} - {r.trial_id for r in replayed.records})
            truth = report.truth
            tension_n = truth.final_tension_n if truth is not None else float("nan")
            print(
                f"| {config.stem} | {int(report.exit_code)} | {report.completed}/{report.planned} "
                f"| {'verified' if report.safe_state_verified else 'NOT verified'} "
                f"| {tension_n:.2f} N "
                f"| {'off' if truth is not None and truth.torque_off else 'ON'} "
                f"| {len(prepared.journal.retried_trials)} | {lost} |"
            )


if __name__ == "__main__":
    main()
