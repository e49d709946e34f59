"""Virtual-time speed of `rig run`: rig seconds simulated per wall second, through the byte-level devices.

Runs a protocol (default: protocols/joint_estimation.yaml) on the built-in simulated rig exactly as
`rig run` does (real drivers, dynamixel-sdk, emulated bus and load cell, world, MCAP logging),
and prints the simulated duration, the wall time and their ratio. Target: >= 50x.

    .venv/bin/python benchmarks/bench_runner.py [--protocol PATH] [--seeds 0 1 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from rig.runner.progress import SilentProgress
from rig.runner.run import RunRequest, execute_run, prepare_run
from rig.sim.simulated_rig import simulated_session

ROOT = Path(__file__).resolve().parent.parent


def one_run(protocol: Path, seed: int, out: Path) -> tuple[float, float, int, int]:
    request = RunRequest(protocol_path=protocol, rig_path=None, out_dir=out, seed=seed, run_id=f"bench{seed}")
    prepared = prepare_run(request)
    session = simulated_session(prepared.config, seed=seed)
    start_virtual_ns = session.clock.monotonic_ns()
    t0 = time.perf_counter()
    report = execute_run(prepared, session, SilentProgress())
    wall_s = time.perf_counter() - t0
    rig_s = (session.clock.monotonic_ns() - start_virtual_ns) / 1e9
    log_bytes = Path(report.log).stat().st_size
    return rig_s, wall_s, report.completed, log_bytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", type=Path, default=ROOT / "protocols" / "joint_estimation.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    args = parser.parse_args()
    print(f"protocol {args.protocol.name}")
    print(f"{'seed':>4} {'trials':>6} {'rig s':>8} {'wall s':>7} {'rig s / wall s':>15} {'log MB':>7}")
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            rig_s, wall_s, trials, log_bytes = one_run(args.protocol, seed, Path(tmp))
            ratios.append(rig_s / wall_s)
            print(
                f"{seed:>4} {trials:>6} {rig_s:>8.1f} {wall_s:>7.2f} {rig_s / wall_s:>14.1f}x "
                f"{log_bytes / 1e6:>7.2f}"
            )
    ratios.sort()
    print(f"median speed: {ratios[len(ratios) // 2]:.1f}x real time (target >= 50x)")


if __name__ == "__main__":
    main()
