"""Python time of one state read of 3 servos through DynamixelServoBus vs the bare SDK doing the same read.

Both run over the in-process transport (virtual time), so what is timed is Python work only: the
SDK packet code, the emulator answering, and (for the driver) its checks, decoding and SI
conversion. The bare SDK reads the same block (122..135: moving .. present position) of the same 3
servos and extracts the same four values per servo with `getData`, without the driver's checks.

Wall time includes preemption by other processes on a shared machine; the thread CPU time
(`time.thread_time_ns`) is the Python work itself.

Run: .venv/bin/python benchmarks/bench_servo_bus.py [--calls N]
"""

from __future__ import annotations

import argparse
import gc
import os
import statistics
import time

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.hw.dxl.bus import DynamixelServoBus
from rig.inputs.rig_config import ServoSpec
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.dxl.inprocess_port import SimPortHandler
from rig.sim.virtual_clock import VirtualClock

IDS = (1, 2, 3)
BLOCK_START, BLOCK_LENGTH = 122, 14


def percentile(samples_ns: list[int], q: float) -> float:
    ordered = sorted(samples_ns)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))] / 1e3


def time_calls(call, n: int) -> tuple[list[int], list[int]]:
    """Per-call wall time and this thread's CPU time (the latter excludes preemption by other processes)."""
    for _ in range(min(200, n)):  # warm-up
        call()
    wall, cpu = [], []
    gc.disable()
    try:
        for _ in range(n):
            c0 = time.thread_time_ns()
            t0 = time.perf_counter_ns()
            call()
            t1 = time.perf_counter_ns()
            cpu.append(time.thread_time_ns() - c0)
            wall.append(t1 - t0)
    finally:
        gc.enable()
    return wall, cpu


def driver_reader(fast: bool):
    clock = VirtualClock()
    bus = EmulatedBus.with_servos(clock, ids=list(IDS))
    specs = [ServoSpec(i, "winch" if i == 1 else "bender", "XM430-W350") for i in IDS]
    driver = DynamixelServoBus("sim", 1_000_000, specs, clock, fast_sync_read=fast,
                               port_factory=lambda n: SimPortHandler(bus, clock, n))  # fmt: skip
    driver.connect()
    assert driver.uses_fast_sync_read == fast
    return driver.read_states, driver


def sdk_reader(fast: bool):
    clock = VirtualClock()
    bus = EmulatedBus.with_servos(clock, ids=list(IDS))
    port = SimPortHandler(bus, clock)
    assert port.openPort() and port.setBaudRate(1_000_000)
    ph = PacketHandler(2.0)
    for i in IDS:  # same setup as the driver's connect: no return delay
        assert ph.write1ByteTxRx(port, i, 9, 0) == (COMM_SUCCESS, 0)
    group = GroupSyncRead(port, ph, BLOCK_START, BLOCK_LENGTH)
    for i in IDS:
        group.addParam(i)
    transfer = group.fastSyncRead if fast else group.txRxPacket

    def read():
        if transfer() != COMM_SUCCESS:
            raise RuntimeError("bare SDK read failed")
        return {
            i: (
                group.getData(i, 132, 4),
                group.getData(i, 128, 4),
                group.getData(i, 126, 2),
                group.getData(i, 122, 1),
            )
            for i in IDS
        }

    return read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=5000)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.calls = 100
    print(f"state read of {len(IDS)} servos, {args.calls} calls each, in-process transport (virtual time)")
    print(f"load average at start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    header = f"{'path':<28}{'wall p50':>10}{'wall p99':>10}{'cpu p50':>10}{'cpu p99':>10}{'cpu mean':>10}"
    print(header + "   (us)")
    for fast in (True, False):
        name = "fast sync read" if fast else "sync read"
        read_driver, driver = driver_reader(fast)
        read_sdk = sdk_reader(fast)
        d_wall, d_cpu = time_calls(read_driver, args.calls)
        s_wall, s_cpu = time_calls(read_sdk, args.calls)
        assert driver.stats.retries == 0 and driver.stats.failures == 0
        for label, wall, cpu in ((f"driver, {name}", d_wall, d_cpu), (f"bare SDK, {name}", s_wall, s_cpu)):
            print(
                f"{label:<28}{percentile(wall, 0.5):>10.1f}{percentile(wall, 0.99):>10.1f}"
                f"{percentile(cpu, 0.5):>10.1f}{percentile(cpu, 0.99):>10.1f}"
                f"{statistics.fmean(cpu) / 1e3:>10.1f}"
            )
        print(
            f"{'  ratio driver/SDK':<28}{percentile(d_wall, 0.5) / percentile(s_wall, 0.5):>10.2f}"
            f"{percentile(d_wall, 0.99) / percentile(s_wall, 0.99):>10.2f}"
            f"{percentile(d_cpu, 0.5) / percentile(s_cpu, 0.5):>10.2f}"
            f"{percentile(d_cpu, 0.99) / percentile(s_cpu, 0.99):>10.2f}"
            f"{statistics.fmean(d_cpu) / statistics.fmean(s_cpu):>10.2f}"
        )
        driver.shutdown()


if __name__ == "__main__":
    main()
