"""Real-time control ticks over ptys: the runner's control loop on a hardware session at the emulators.

`rig sim servos --ids 1,2 --usb-latency-ms L` and `rig sim loadcell --rate 1000` run as subprocesses
on ptys; the real drivers (`DynamixelServoBus` with the system clock, `SerialLoadCell` with its
reader thread) talk to them as to a U2D2 and a load-cell board. The runner's own `ControlLoop` ticks
at the protocol's default period (20 ms) for `--seconds`, as it does while a trial waits: one sync
read of both servos and a drain of the load cell per tick (the log and the interlocks are left out).
Reported per emulated USB latency timer (1 ms: the udev rule's; 16 ms: Linux's default for FTDI):

* tick period: the interval between consecutive ticks' reads, p50 / p99 / max, and p99 over nominal;
* late ticks: ticks that found their due time already passed when they came to wait (the previous
  tick's work took longer than a period), and how late the worst one was;
* reads failed after retries: state reads with no reply within the SDK's window after the driver's
  retries (a run would stop the trial there); the benchmark counts them and goes on.

Target (issue 22): with 1 ms the tick holds, p99 <= 1.2 x nominal.

    .venv/bin/python benchmarks/bench_realtime_pty.py [--seconds 20] [--latency-ms 1 16]
"""

from __future__ import annotations

import argparse
import itertools
import os
import select
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.errors import CommunicationError, RigTimeoutError
from rig.hw.clock import SystemClock
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.loadcell.calibration import Calibration
from rig.hw.loadcell.driver import SerialLoadCell
from rig.hw.session import RigSession
from rig.inputs.rig_config import ServoSpec
from rig.runner.control_loop import ControlLoop
from rig.safety.interlocks import CurrentAtLimit, ForceCeiling
from rig.vocabulary import RigKind, ServoModel, ServoRole

PERIOD_S = 0.02  # the protocol's default control_period_s
ROLES = {1: ServoRole.WINCH, 2: ServoRole.BENDER}
SPECS = (
    ServoSpec(1, ServoRole.WINCH, ServoModel.XM430_W350),
    ServoSpec(2, ServoRole.BENDER, ServoModel.XM430_W350),
)


def start(cmd: list[str]) -> subprocess.Popen[str]:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 20)
    if not ready or proc.stdout is None or not proc.stdout.readline().startswith("PTY"):
        proc.kill()
        raise SystemExit(f"emulator did not start: {' '.join(cmd)}")
    return proc


class _NoRecorder:
    """The recorder's place in the loop, logging nothing (the log's cost is not what this measures)."""

    failed = None

    def tick_rows(self, *args: object) -> None:
        pass

    def note(self, *args: object) -> None:  # the loop's warnings: a late tick, a slow latency timer
        pass


@dataclass
class Result:
    latency_ms: float
    ticks: int
    p50_ms: float
    p99_ms: float
    max_ms: float
    late: int
    worst_late_ms: float
    failed_reads: int

    def row(self) -> str:
        return (
            f"| {self.latency_ms:g} ms | {self.ticks} | {self.p50_ms:.2f} | {self.p99_ms:.2f} | "
            f"{self.max_ms:.2f} | "
            f"{self.p99_ms / (PERIOD_S * 1e3):.3f}x | {self.late} ({100 * self.late / self.ticks:.1f} %) | "
            f"{self.worst_late_ms:.1f} | {self.failed_reads} |"
        )


def measure(latency_ms: float, seconds: float, tmp: Path, late_tick: bool = False) -> Result:
    """`late_tick`: make the 10th tick a period late (smoke mode: the loop's late-tick path runs)."""
    servo_link, cell_link = tmp / f"dxl{latency_ms:g}", tmp / f"cell{latency_ms:g}"
    servo_proc = start([sys.executable, "-m", "rig.cli.sim_servos", "--ids", "1,2", "--link", str(servo_link),
                        "--usb-latency-ms", str(latency_ms)])  # fmt: skip
    cell_proc = start([sys.executable, "-m", "rig.cli", "sim", "loadcell", "--link", str(cell_link),
                       "--rate", "1000", "--profile", "constant:0"])  # fmt: skip
    clock = SystemClock()
    servos = DynamixelServoBus(str(servo_link), 1_000_000, SPECS, clock, bus_watchdog_ms=500)
    calibration = Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-27", "bench", "rig-lc1")
    cell = SerialLoadCell(str(cell_link), baud=921600, calibration=calibration, clock=clock)
    session = RigSession(
        kind=RigKind.HARDWARE, clock=clock, servos=servos, load_cell=cell, operator=SimpleNamespace(),
        fixture=SimpleNamespace(), configuration=None, winch_id=1, roles=ROLES,
    )  # fmt: skip
    loop = ControlLoop(
        session, _NoRecorder(), period_s=PERIOD_S,  # type: ignore[arg-type]
        ceiling=ForceCeiling(75.0), current_limit=CurrentAtLimit(1, 0.52, 1.0),
    )  # fmt: skip
    read_starts: list[int] = []
    failed = 0
    lateness_ns: list[int] = []
    read_states = servos.read_states

    def timed_read() -> dict:  # type: ignore[type-arg]
        now = time.monotonic_ns()
        read_starts.append(now)
        return read_states()

    servos.read_states = timed_read  # type: ignore[method-assign]
    try:
        servos.connect()
        cell.open()
        loop.restart_pacing()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if late_tick and len(lateness_ns) == 10:
                time.sleep(2 * PERIOD_S)
            due = loop._next_tick_ns + loop.period_ns
            came = time.monotonic_ns()
            try:
                loop.tick(interlocks=False)
            except (RigTimeoutError, CommunicationError):  # a run would stop the trial; counted here
                failed += 1
            lateness_ns.append(came - due)
    finally:
        servos.shutdown()
        cell.close()
        for proc in (servo_proc, cell_proc):
            proc.terminate()
            proc.communicate(timeout=10)
    periods_ms = sorted((b - a) / 1e6 for a, b in itertools.pairwise(read_starts[1:]))
    late = [x / 1e6 for x in lateness_ns if x > 0]
    return Result(
        latency_ms=latency_ms,
        ticks=len(periods_ms),
        p50_ms=statistics.median(periods_ms),
        p99_ms=periods_ms[min(len(periods_ms) - 1, int(0.99 * len(periods_ms)))],
        max_ms=periods_ms[-1],
        late=len(late),
        worst_late_ms=max(late, default=0.0),
        failed_reads=failed,
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=20.0, help="ticking time per latency (default 20)")
    parser.add_argument("--latency-ms", type=float, nargs="+", default=[1.0, 16.0])
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # both latencies, 20 ticks each, one of them (the 11th) late
        args.seconds = 0.4
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        results = [measure(latency, args.seconds, Path(tmp), args.smoke) for latency in args.latency_ms]
    load_after = os.getloadavg()[0]
    print(
        f"control period {PERIOD_S * 1e3:g} ms, {args.seconds:g} s per latency; "
        f"load average {load_before:.1f} -> {load_after:.1f} on {os.cpu_count()} cores"
    )
    header = ["USB latency", "ticks", "period p50 ms", "p99 ms", "max ms", "p99 / nominal", "late ticks",
              "worst late ms", "reads failed after retries"]  # fmt: skip
    print("| " + " | ".join(header) + " |")
    print("|---" * len(header) + "|")
    for result in results:
        print(result.row())


if __name__ == "__main__":
    main()
