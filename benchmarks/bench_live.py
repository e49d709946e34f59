"""`rig run --live` overhead: wall time with a subscribed Foxglove client vs without; a stalled client.

Each round runs the same simulated protocol (virtual time, as fast as the CPU allows) four ways, each
`rig run` in its own process: `plain`; `none`, `--live` with no client; `live`, `--live` with a
client (another process) subscribed to every topic and reading everything; `stall`, `--live` with a
client that subscribes to every topic, with a 4 KiB receive window, and then never reads. The run's
last `/rig/log` message holds the live view's counts (published, dropped, slow-client overflows).

    .venv/bin/python benchmarks/bench_live.py --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = """\
format: rig-protocol/1
name: bench-live
detector: {arm_threshold_n: 2.0, drop_fraction: 0.15}
ramp: {fast_speed_rad_s: 1.0, slow_speed_rad_s: 0.3, max_force_n: 70.0}
limits: {force_ceiling_n: 75.0}
blocks:
  - kind: joint_estimation
    joint: 1
    distances_m: [0.12, 0.16, 0.2, 0.25]
    repeats: REPEATS
    steps: [prompt, {tare: {settle_s: 0.1}}, ramp_until_slip, unload]
"""

CLIENT = r"""
import asyncio, json, socket, sys, websockets
url, mode = sys.argv[1], sys.argv[2]
host, port = url[5:].split(":")
PROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
async def main():
    for _ in range(500):
        sock = socket.socket()
        if mode == "stall":  # a small window: the server's outbox, not the kernel, holds the backlog
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        try:
            sock.connect((host, int(port)))
            break
        except OSError:
            sock.close()
            await asyncio.sleep(0.01)
    ws = await websockets.connect(url, sock=sock, subprotocols=PROTOCOLS, max_size=None, max_queue=4)
    n = 0
    async with ws:
        async for frame in ws:
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    subs = [{"id": c["id"], "channelId": c["id"]} for c in msg["channels"]]
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    print("subscribed", flush=True)
                    if mode == "stall":
                        await asyncio.sleep(3600)  # never reads again: the server's outbox fills
            else:
                n += 1
    print(n, flush=True)
asyncio.run(main())
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def last_log(path: Path) -> str:
    text = ""
    with path.open("rb") as f:
        for _s, _channel, message in make_reader(f).iter_messages(topics=["/rig/log"]):
            text = json.loads(message.data)["message"]
    return text


def run_once(work: Path, name: str, client: str | None, repeats: int) -> tuple[float, float, str, str]:
    """Wall and CPU time of one `rig run`, the live view's log line, and what the client received."""
    protocol = work / "p.yaml"
    protocol.write_text(PROTOCOL.replace("REPEATS", str(repeats)))
    cmd = [sys.executable, "-m", "rig.cli", "run", str(protocol), "--out", str(work / name), "--json"]
    cmd += ["--run-id", name]
    reader = None
    if client is not None:
        port = free_port()
        cmd += ["--live", "--live-port", str(port)]
    if client == "none":
        cmd += ["--live", "--live-port", "0"]
        client = None
    start = time.perf_counter()
    run = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
    if client is not None:
        url = f"ws://127.0.0.1:{port}"
        reader = subprocess.Popen(
            [sys.executable, "-c", CLIENT, url, client], stdout=subprocess.PIPE, text=True
        )
        assert reader.stdout is not None
        reader.stdout.readline()  # subscribed (the run is already going: this wait is part of its time)
    _pid, status, usage = os.wait4(run.pid, 0)
    elapsed = time.perf_counter() - start
    run.returncode = os.waitstatus_to_exitcode(status)
    assert run.returncode == 0, f"{name}: exit {run.returncode}"
    cpu = usage.ru_utime + usage.ru_stime
    received = ""
    if reader is not None:
        if client == "stall":
            reader.kill()
        out, _ = reader.communicate(timeout=60)
        received = out.strip() or "(killed)"
    return elapsed, cpu, last_log(work / name / f"{name}.mcap"), received


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3, help="repeats of the 4 distances in the protocol")
    args = parser.parse_args()
    kinds = ("plain", "none", "live", "stall")
    wall: dict[str, list[float]] = {kind: [] for kind in kinds}
    cpu: dict[str, list[float]] = {kind: [] for kind in kinds}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for r in range(args.rounds):
            for kind in kinds:
                client = None if kind == "plain" else kind
                elapsed, used, line, received = run_once(work, f"{kind}{r}", client, args.repeats)
                wall[kind].append(elapsed)
                cpu[kind].append(used)
                print(
                    f"round {r} {kind:6s} {elapsed:6.2f} s wall {used:6.2f} s CPU  "
                    f"client received {received or '-'}  {line}",
                    flush=True,
                )

    def median(values: list[float]) -> float:
        return sorted(values)[len(values) // 2]

    base_wall, base_best, base_cpu = median(wall["plain"]), min(wall["plain"]), median(cpu["plain"])
    for kind in kinds:
        mid, best, used = median(wall[kind]), min(wall[kind]), median(cpu[kind])
        print(
            f"{kind:6s} wall median {mid:6.2f} s ({mid / base_wall:4.2f}x)  best {best:6.2f} s "
            f"({best / base_best:4.2f}x)  CPU median {used:6.2f} s ({used / base_cpu:4.2f}x)"
        )


if __name__ == "__main__":
    main()
