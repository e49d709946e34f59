"""Benchmark of the Dynamixel emulator through the real dynamixel_sdk.

pty (subprocess `rig.cli.sim_servos`): N sync reads of 3 servos (Present Current..Position, 10 bytes),
reply latency p50/p99/max and the number of failed transactions; compared with a canned responder
(a subprocess that answers every request with precomputed bytes, like a byte-stub mock) in the same run.
In-process (`SimPortHandler`): sync-read transactions per second and virtual-vs-wall time ratio,
compared with the SDK on a fake serial port that returns the same canned bytes.
`--soak N`: N mixed transactions (ping, read, write, sync/bulk/fast read) over the pty; exit 1 on any failure.
`--cpu`: only the main-thread CPU cost of what `rig run` does on the simulated rig: (a) one fast sync
read of 2 servos (Moving..Present Position, 14 bytes) through the SDK on `SimPortHandler`, and (b) a
10 s winch ramp integrated in 1 ms steps (`EmulatedBus.advance_to`, as the world's substeps call it);
median CPU time of 5 repetitions, plus a digest of the bytes and floats so runs can be compared.

    .venv/bin/python benchmarks/bench_dxl_emulator.py [--reads 5000] [--soak 1000]
    .venv/bin/python benchmarks/bench_dxl_emulator.py --cpu
"""

from __future__ import annotations

import argparse
import hashlib
import os
import select
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dynamixel_sdk import (
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    PacketHandler,
    PortHandler,
)
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.hw.dxl import control_table as ct
from rig.sim.dxl import packet as p
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.dxl.inprocess_port import SimPortHandler
from rig.sim.virtual_clock import VirtualClock

IDS = (1, 2, 3)
ADDR, LENGTH = 126, 10  # Present Current, Velocity, Position
BAUD = 1_000_000


def canned_replies() -> tuple[bytes, bytes]:
    """The sync-read request the SDK sends and the three status packets that answer it."""
    request = p.build_instruction(
        p.BROADCAST_ID, p.SYNC_READ, bytes((ADDR, 0, LENGTH, 0, *IDS)), stuffed=False
    )
    reply = b"".join(p.build_status(i, 0, bytes(LENGTH)) for i in IDS)
    return request, reply


def serve_canned(link: str) -> None:
    """Child mode: answer every complete packet with the canned reply, nothing else."""
    from rig.sim.pty_port import PtyPort, StopFlag

    _, reply = canned_replies()
    stop = StopFlag()
    with PtyPort(link) as pty:
        print(f"PTY {pty.slave_name} LINK {link}", flush=True)
        framer = p.Framer()
        poller = select.poll()
        poller.register(pty.master_fd, select.POLLIN)
        while not stop.stopped:
            if poller.poll(50):
                for _ in framer.feed(pty.read(), time.monotonic_ns()):
                    pty.write(reply)


def start(cmd: list[str]) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 10)
    line = proc.stdout.readline() if ready else ""  # type: ignore[union-attr]
    words = line.split()
    if len(words) != 4 or words[0] != "PTY":
        proc.kill()
        raise RuntimeError(f"server did not start: {line!r}")
    return proc, words[3]


def start_emulator(link_path: str) -> tuple[subprocess.Popen[str], str]:
    """`rig sim servos` with three XM430-W350 at BAUD, in its own process."""
    cmd = [sys.executable, "-m", "rig.cli.sim_servos", "--ids", "1,2,3", "--baud", str(BAUD)]
    return start([*cmd, "--link", link_path])


def stop(proc: subprocess.Popen[str]) -> None:
    proc.terminate()
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


def sync_read_latencies(link: str, n: int) -> tuple[list[float], int]:
    port = PortHandler(link)
    assert port.openPort() and port.setBaudRate(BAUD)
    ph = PacketHandler(2.0)
    group = GroupSyncRead(port, ph, ADDR, LENGTH)
    for i in IDS:
        group.addParam(i)
    latencies: list[float] = []
    failures = 0
    for _ in range(200):  # warm-up
        group.txRxPacket()
    for _ in range(n):
        t0 = time.perf_counter_ns()
        result = group.txRxPacket()
        latencies.append((time.perf_counter_ns() - t0) / 1e6)
        if result != COMM_SUCCESS:
            failures += 1
    port.closePort()
    return latencies, failures


def summary(latencies: list[float]) -> dict[str, float]:
    s = sorted(latencies)
    return {
        "p50_ms": statistics.median(s),
        "p99_ms": s[int(0.99 * (len(s) - 1))],
        "max_ms": s[-1],
    }


def bench_pty(n: int, tmp: str) -> None:
    emu, link = start_emulator(f"{tmp}/emu")
    try:
        emu_lat, emu_fail = sync_read_latencies(link, n)
    finally:
        stop(emu)
    canned, link = start([sys.executable, __file__, "--serve-canned", f"{tmp}/canned"])
    try:
        can_lat, can_fail = sync_read_latencies(link, n)
    finally:
        stop(canned)
    e, c = summary(emu_lat), summary(can_lat)
    print(f"pty, {n} sync reads of {len(IDS)} servos x {LENGTH} bytes at {BAUD} baud, wall time per call:")
    for name, stats, fails in (("emulator", e, emu_fail), ("canned  ", c, can_fail)):
        print(
            f"  {name} : p50 {stats['p50_ms']:.3f} ms  p99 {stats['p99_ms']:.3f} ms  "
            f"max {stats['max_ms']:.3f} ms  failures {fails}"
        )
    print(
        f"  ratio emulator/canned: p50 {e['p50_ms'] / c['p50_ms']:.2f}  p99 {e['p99_ms'] / c['p99_ms']:.2f}"
    )


class CannedSerial:
    """A fake serial port that answers the sync-read request with canned bytes (no emulator)."""

    def __init__(self, exchange: tuple[bytes, bytes] | None = None) -> None:
        self.request, self.reply = exchange or canned_replies()
        self.rx = bytearray()
        self.is_open = True

    def write(self, data: list[int]) -> int:
        if bytes(data) == self.request:
            self.rx += self.reply
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        self.is_open = False


class CannedPortHandler(PortHandler):
    exchange: tuple[bytes, bytes] | None = None  # (request, reply); None: the 3-servo sync read

    def setupPort(self, cflag_baud: int) -> bool:
        self.ser = CannedSerial(self.exchange)
        self.is_open = True
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


def bench_inprocess(n: int) -> None:
    clock = VirtualClock()
    bus = EmulatedBus.with_servos(clock, ids=IDS)
    clock.on_advance(bus.advance_to)
    runs = {}
    for name, port in (("emulator", SimPortHandler(bus, clock)), ("canned", CannedPortHandler("canned"))):
        assert port.openPort() and port.setBaudRate(BAUD)
        ph = PacketHandler(2.0)
        group = GroupSyncRead(port, ph, ADDR, LENGTH)
        for i in IDS:
            group.addParam(i)
        v0, t0 = clock.monotonic_ns(), time.perf_counter_ns()
        failures = sum(group.txRxPacket() != COMM_SUCCESS for _ in range(n))
        wall_s = (time.perf_counter_ns() - t0) / 1e9
        runs[name] = (n / wall_s, (clock.monotonic_ns() - v0) / 1e9 / wall_s, failures)
    (emu_tps, ratio, emu_fail), (can_tps, _, can_fail) = runs["emulator"], runs["canned"]
    print(f"in-process, {n} sync reads of {len(IDS)} servos x {LENGTH} bytes:")
    print(f"  emulator : {emu_tps:,.0f} transactions/s, virtual/wall time {ratio:.1f}x, failures {emu_fail}")
    print(f"  canned   : {can_tps:,.0f} transactions/s, failures {can_fail}")
    print(f"  ratio emulator/canned throughput: {emu_tps / can_tps:.2f}")


def soak(n: int, tmp: str) -> int:
    emu, link = start_emulator(f"{tmp}/soak")
    failures: dict[str, int] = {}
    try:
        port = PortHandler(link)
        assert port.openPort() and port.setBaudRate(BAUD)
        ph = PacketHandler(2.0)
        sr = GroupSyncRead(port, ph, ADDR, LENGTH)
        br = GroupBulkRead(port, ph)
        for i in IDS:
            sr.addParam(i)
        br.addParam(1, 132, 4)
        br.addParam(2, 64, 1)
        br.addParam(3, 0, 2)
        steps = [
            ("ping", lambda k: ph.ping(port, IDS[k % 3])[1]),
            ("read4", lambda k: ph.read4ByteTxRx(port, IDS[k % 3], 132)[1]),
            ("write1", lambda k: ph.write1ByteTxRx(port, IDS[k % 3], 65, k & 1)[0]),
            ("sync_read", lambda k: sr.txRxPacket()),
            ("bulk_read", lambda k: br.txRxPacket()),
            ("fast_sync_read", lambda k: sr.fastSyncRead()),
        ]
        t0 = time.perf_counter()
        for k in range(n):
            name, call = steps[k % len(steps)]
            if call(k) != COMM_SUCCESS:
                failures[name] = failures.get(name, 0) + 1
        elapsed = time.perf_counter() - t0
        port.closePort()
    finally:
        stop(emu)
    total = sum(failures.values())
    print(f"soak over pty: {n} mixed transactions in {elapsed:.2f} s, failures {total} {failures or ''}")
    return 1 if total else 0


STATE_ADDR, STATE_LENGTH = 122, 14  # Moving .. Present Position, the block `read_states` reads
CPU_REPEATS = 7


def _torque_on(
    bus: EmulatedBus, servo_id: int, mode: int, now_ns: int, goal_current: int | None = None
) -> None:
    servo = bus.servo(servo_id)
    servo.write(ct.ADDR_OPERATING_MODE, bytes((mode,)), now_ns)
    if goal_current is not None:
        servo.write(102, goal_current.to_bytes(2, "little"), now_ns)  # Goal Current
    servo.write(ct.ADDR_TORQUE_ENABLE, b"\x01", now_ns)


def _fast_read_group(port: PortHandler) -> GroupSyncRead:
    assert port.openPort() and port.setBaudRate(BAUD)
    group = GroupSyncRead(port, PacketHandler(2.0), STATE_ADDR, STATE_LENGTH)
    for sid in (1, 2):
        group.addParam(sid)
    return group


def _timed_reads(group: GroupSyncRead, n: int) -> float:
    fast_read = group.fastSyncRead
    t0 = time.thread_time()
    for _ in range(n):
        if fast_read() != COMM_SUCCESS:
            raise RuntimeError("fast sync read failed")
    return (time.thread_time() - t0) / n * 1e6


def cpu_fast_sync_read(n: int) -> tuple[float, float, str]:
    """CPU µs per fast sync read of 2 servos through the SDK on the in-process port; the same with canned
    bytes (the SDK's own share); a digest of everything the host received.

    Servo 1 ramps in mode 5 at 1 rad/s (its state block changes every read), servo 2 holds.
    """
    clock = VirtualClock()
    bus = EmulatedBus.with_servos(clock, ids=(1, 2))
    clock.on_advance(bus.advance_to)
    for sid in (1, 2):
        bus.servo(sid).write(9, b"\x00", 0)  # Return Delay Time 0, as the driver configures
    _torque_on(bus, 1, 5, 0, goal_current=800)
    _torque_on(bus, 2, 4, 0)
    bus.servo(1).write(112, round(1.0 / ct.RAD_S_PER_VELOCITY_UNIT).to_bytes(4, "little"), 0)
    bus.servo(1).write(116, (1 << 30).to_bytes(4, "little"), 0)  # Goal Position: far away
    port = SimPortHandler(bus, clock)
    group = _fast_read_group(port)
    digest = hashlib.sha256()
    received: list[bytes] = []
    feed = bus.feed

    def recording_feed(data: bytes, now_ns: int) -> list:
        replies = feed(data, now_ns)
        received.extend(r.data for r in replies)
        return replies

    bus.feed = recording_feed  # type: ignore[method-assign]
    us = _timed_reads(group, n)
    for data in received:
        digest.update(data)
    digest.update(struct.pack("<QQ", clock.monotonic_ns(), port.ser.bytes_read))
    request = p.build_instruction(
        p.BROADCAST_ID, p.FAST_SYNC_READ, bytes((STATE_ADDR, 0, STATE_LENGTH, 0, 1, 2)), stuffed=False
    )
    canned = CannedPortHandler("canned")
    canned.exchange = (request, received[-1])
    canned_us = _timed_reads(_fast_read_group(canned), n)
    return us, canned_us, digest.hexdigest()[:16]


def cpu_winch_ramp(seconds: float = 10.0) -> tuple[float, str]:
    """CPU µs per 1 ms step of a winch ramp (mode 5, 1 rad/s profile) against a spring line, and a digest.

    A second servo holds still with torque on (the bender), as on the rig. The world's order per
    substep: advance the bus, read the winch angle, set the line torque.
    """
    bus = EmulatedBus.with_servos(None, ids=(1, 2))
    winch, bender = bus.servo(1), bus.servo(2)
    _torque_on(bus, 1, 5, 0, goal_current=800)
    _torque_on(bus, 2, 4, 0)
    winch.write(112, round(1.0 / ct.RAD_S_PER_VELOCITY_UNIT).to_bytes(4, "little"), 0)  # Profile Velocity
    theta0 = winch.present_position_rad
    goal = round((theta0 + 1.2 * seconds) / ct.RAD_PER_PULSE)
    winch.write(116, goal.to_bytes(4, "little", signed=True), 0)  # Goal Position
    digest = hashlib.sha256()
    steps = round(seconds * 1000)
    t0 = time.thread_time()
    for k in range(1, steps + 1):
        bus.advance_to(k * 1_000_000)
        theta = winch.present_position_rad
        winch.external_torque_nm = -0.06 * max(0.0, theta - theta0 - 0.5)  # slack, then a spring line
    cpu_s = time.thread_time() - t0
    for servo in (winch, bender):
        s = servo.state
        digest.update(
            struct.pack(
                "<5d",
                s.position_rad,
                s.velocity_rad_s,
                s.motor_torque_nm,
                s.ref_position_rad,
                s.ref_velocity_rad_s,
            )
        )
    return cpu_s / steps * 1e6, digest.hexdigest()[:16]


def bench_cpu(reads: int, repeats: int = CPU_REPEATS) -> None:
    """Median CPU time of (a) and (b) over `repeats` repetitions, after one warm-up."""
    reads_us, canned_us, ramps_us = [], [], []
    digests = set()
    for k in range(repeats + 1):
        us, c_us, d_read = cpu_fast_sync_read(reads)
        ramp_us, d_ramp = cpu_winch_ramp()
        digests.add((d_read, d_ramp))
        if k:
            reads_us.append(us)
            canned_us.append(c_us)
            ramps_us.append(ramp_us)
    ((d_read, d_ramp),) = digests
    print(
        f"(a) fast sync read of 2 servos, SDK on SimPortHandler: {statistics.median(reads_us):.1f} µs CPU "
        f"per read (min {min(reads_us):.1f}; SDK alone on canned bytes {statistics.median(canned_us):.1f}; "
        f"{reads} reads x {repeats}), digest {d_read}"
    )
    print(
        f"(b) winch ramp 10 s in 1 ms steps, 2 servos: {statistics.median(ramps_us):.2f} µs CPU per step "
        f"(min {min(ramps_us):.2f}; x {repeats}), digest {d_ramp}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=5000)
    parser.add_argument("--inprocess", type=int, default=20000)
    parser.add_argument("--soak", type=int, default=0, help="also run N mixed transactions over the pty")
    parser.add_argument("--cpu", action="store_true", help="only the in-process CPU costs (a) and (b)")
    parser.add_argument("--serve-canned", metavar="LINK", help=argparse.SUPPRESS)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # the pty, in-process and soak measurements small, then the CPU costs
        args.reads, args.inprocess, args.soak = 50, 200, 50
    if args.serve_canned:
        serve_canned(args.serve_canned)
        return 0
    if args.cpu:
        bench_cpu(2000)
        return 0
    print(f"host: {os.cpu_count()} cpus, load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        bench_pty(args.reads, tmp)
        bench_inprocess(args.inprocess)
        code = soak(args.soak, tmp) if args.soak else 0
    if args.smoke and code == 0:
        bench_cpu(200, repeats=1)
    return code


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
