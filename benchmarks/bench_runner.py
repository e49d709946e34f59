"""Virtual-time speed of `rig run`: rig seconds simulated per wall second, through the byte-level devices.

Runs a protocol (default: protocols/joint_estimation.yaml) on the built-in simulated rig exactly as
`rig run` does (real drivers, dynamixel-sdk, emulated bus and load cell, world, MCAP logging),
and prints the simulated duration, the wall time and their ratio. Target: >= 50x.

`--parts` also prints where the acquisition thread's CPU time goes (thread CPU time around the
runner's per-tick calls), per millisecond of rig time. `--control-period-s` runs a copy of the
protocol with another control period (what-if; the shipped protocol is what counts).

    .venv/bin/python benchmarks/bench_runner.py [--protocol PATH] [--seeds 0 1 2] [--parts] [--smoke]
"""

from __future__ import annotations

import argparse
import collections
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from rig.rigs import open_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parent.parent


def one_run(protocol: Path, seed: int, out: Path) -> tuple[float, float, int, int]:
    request = RunRequest(protocol_path=protocol, rig_path=None, out_dir=out, seed=seed, run_id=f"bench{seed}")
    prepared = prepare_run(request)
    rig = open_rig(prepared)
    clock = rig.session.clock
    start_virtual_ns = clock.monotonic_ns()
    t0 = time.perf_counter()
    report = execute_run(prepared, rig, SilentProgress())
    wall_s = time.perf_counter() - t0
    rig_s = (clock.monotonic_ns() - start_virtual_ns) / 1e9
    log_bytes = Path(report.log).stat().st_size
    return rig_s, wall_s, report.completed, log_bytes


def instrument_parts() -> collections.Counter[str]:
    """Wrap the runner's per-tick calls to add up the calling thread's CPU time per part."""
    from rig.hw.dxl.bus import DynamixelServoBus
    from rig.hw.loadcell.driver import SerialLoadCell
    from rig.log.writing.writer import RunLogger
    from rig.runner.control_loop import ControlLoop
    from rig.sim.virtual_clock import VirtualClock

    totals: collections.Counter[str] = collections.Counter()

    def wrap(cls: type, name: str, part: str, clock: Callable[[], float] = time.thread_time) -> None:
        original: Callable[..., Any] = getattr(cls, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            start = clock()
            try:
                return original(*args, **kwargs)
            finally:
                totals[part] += clock() - start

        setattr(cls, name, timed)

    wrap(ControlLoop, "tick", "tick (all of the below and the interlocks)")
    wrap(VirtualClock, "sleep", "  clock sleep: world, servo and load-cell emulation")
    wrap(DynamixelServoBus, "read_states", "  servo state read (SDK + emulated bus)")
    wrap(SerialLoadCell, "poll", "  load-cell poll (bytes to samples)")
    wrap(ControlLoop, "ingest", "  runner ingest and logging calls")
    wrap(RunLogger, "flush", "wall time waiting for the writer process to flush (not CPU)", time.perf_counter)
    return totals


def with_control_period(protocol: Path, period_s: float, out: Path) -> Path:
    """A copy of `protocol` with `control_period_s` replaced."""
    data = yaml.safe_load(protocol.read_text(encoding="utf-8"))
    data["control_period_s"] = period_s
    copy = out / f"{protocol.stem}-period-{period_s:g}.yaml"
    copy.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return copy


def main() -> None:
    # Here, not above: the other benchmarks import `one_run` from `benchmarks.bench_runner`.
    from smoke_mode import SMOKE_HELP, short_protocol  # benchmarks/ is the script's directory

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--protocol", type=Path, default=ROOT / "protocols" / "joint_estimation.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--parts", action="store_true", help="CPU time per part of the tick")
    parser.add_argument("--control-period-s", type=float, help="run a copy with this control period")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # a one-trial copy of the protocol, one seed, with the parts and a control period
        args.seeds, args.parts, args.control_period_s = [0], True, 0.02
    parts = instrument_parts() if args.parts else None
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        protocol = short_protocol(Path(tmp), args.protocol, trials=1) if args.smoke else args.protocol
        if args.control_period_s is not None:
            protocol = with_control_period(protocol, args.control_period_s, Path(tmp))
        print(f"protocol {protocol.name}")
        print(f"{'seed':>4} {'trials':>6} {'rig s':>8} {'wall s':>7} {'rig s / wall s':>15} {'log MB':>7}")
        for seed in args.seeds:
            if parts is not None:
                parts.clear()
            cpu0 = time.thread_time()
            rig_s, wall_s, trials, log_bytes = one_run(protocol, seed, Path(tmp))
            cpu_s = time.thread_time() - cpu0
            ratios.append(rig_s / wall_s)
            print(
                f"{seed:>4} {trials:>6} {rig_s:>8.1f} {wall_s:>7.2f} {rig_s / wall_s:>14.1f}x "
                f"{log_bytes / 1e6:>7.2f}"
            )
            if parts is not None:
                per_ms = cpu_s / rig_s * 1e3
                print(f"       acquisition thread CPU {cpu_s:.2f} s = {per_ms:.1f} us per rig ms:")
                for part, seconds in parts.items():
                    print(f"       {seconds / rig_s * 1e3:6.1f} us per rig ms  {part}")
    ratios.sort()
    print(f"median speed: {ratios[len(ratios) // 2]:.1f}x real time")


if __name__ == "__main__":
    main()
