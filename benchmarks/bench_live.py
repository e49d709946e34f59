"""`rig run --live` overhead: wall time with a subscribed Foxglove client vs without; a stalled client.

Each round runs the same simulated protocol (virtual time, as fast as the CPU allows) four ways, each
`rig run` in its own process: `plain`; `none`, `--live` with no client; `live`, `--live` with a
client (another process) subscribed to every topic and reading everything; `stall`, `--live` with a
client that subscribes to every topic, with a 4 KiB receive window, and then never reads. The run's
last `/rig/log` message holds the live view's counts (published, dropped, slow-client reports).
With `--baseline-tree DIR` each round also runs `plain` and `live` with the code of another checkout
(`base-plain`, `base-live`), interleaved with the others, for a side-by-side comparison.

CPU is split into the `rig run` process's own (the acquisition loop and its threads) and that of its
child processes (the MCAP writer, the live view's server), read from /proc before the run is reaped.

    .venv/bin/python benchmarks/bench_live.py --rounds 5 [--baseline-tree ../main]
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
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

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
    distances_m: DISTANCES
    repeats: REPEATS
    steps: [prompt, {tare: {settle_s: 0.1}}, ramp_until_slip, unload]
"""

DISTANCES_M = "[0.12, 0.16, 0.2, 0.25]"

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


def _own_and_children_cpu(pid: int) -> tuple[float, float]:
    """CPU seconds of an exited, not yet reaped process: its own, and its reaped children's."""
    os.waitid(os.P_PID, pid, os.WEXITED | os.WNOWAIT)
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    tick = os.sysconf("SC_CLK_TCK")
    utime, stime, cutime, cstime = (int(f) / tick for f in fields[11:15])
    return utime + stime, cutime + cstime


def run_once(
    work: Path, name: str, client: str | None, repeats: int, tree: Path = ROOT, distances: str = DISTANCES_M
) -> tuple[float, float, float, str, str]:
    """Wall time, own and children's CPU of one `rig run`, the live view's log line, what the client got."""
    protocol = work / "p.yaml"
    protocol.write_text(PROTOCOL.replace("REPEATS", str(repeats)).replace("DISTANCES", distances))
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
    env = {**os.environ, "PYTHONPATH": str(tree)}
    run = subprocess.Popen(cmd, cwd=tree, stdout=subprocess.DEVNULL, env=env)
    if client is not None:
        url = f"ws://127.0.0.1:{port}"
        reader = subprocess.Popen(
            [sys.executable, "-c", CLIENT, url, client], stdout=subprocess.PIPE, text=True
        )
        assert reader.stdout is not None
        reader.stdout.readline()  # subscribed (the run is already going: this wait is part of its time)
    own, children = _own_and_children_cpu(run.pid)
    elapsed = time.perf_counter() - start
    _pid, status = os.waitpid(run.pid, 0)
    run.returncode = os.waitstatus_to_exitcode(status)
    assert run.returncode == 0, f"{name}: exit {run.returncode}"
    received = ""
    if reader is not None:
        if client == "stall":
            reader.kill()
        out, _ = reader.communicate(timeout=60)
        received = out.strip() or "(killed)"
    return elapsed, own, children, last_log(work / name / f"{name}.mcap"), received


def median(values: list[float]) -> float:
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else (ordered[mid - 1] + ordered[mid]) / 2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3, help="repeats of the 4 distances in the protocol")
    parser.add_argument("--baseline-tree", type=Path, help="another checkout to run plain and live with")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    distances = DISTANCES_M
    if args.smoke:  # one round of the four ways, one trial each
        args.rounds, args.repeats, distances = 1, 1, "[0.25]"
    kinds = ["plain", "none", "live", "stall"]
    if args.baseline_tree is not None:
        kinds += ["base-plain", "base-live"]
    wall: dict[str, list[float]] = {kind: [] for kind in kinds}
    own: dict[str, list[float]] = {kind: [] for kind in kinds}
    children: dict[str, list[float]] = {kind: [] for kind in kinds}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for r in range(args.rounds):
            for kind in kinds:
                tree = ROOT
                mode = kind
                if kind.startswith("base-"):
                    tree, mode = args.baseline_tree.resolve(), kind.removeprefix("base-")
                client = None if mode == "plain" else mode
                elapsed, used, child, line, received = run_once(
                    work, f"{kind}{r}", client, args.repeats, tree, distances
                )
                wall[kind].append(elapsed)
                own[kind].append(used)
                children[kind].append(child)
                print(
                    f"round {r} {kind:10s} {elapsed:6.2f} s wall {used:6.2f} s CPU "
                    f"(+{child:5.2f} s children)  client received {received or '-'}  {line}",
                    flush=True,
                )

    for kind in kinds:
        base = "base-plain" if kind.startswith("base-") else "plain"
        mid, best, used, child = (
            median(wall[kind]),
            min(wall[kind]),
            median(own[kind]),
            median(children[kind]),
        )
        print(
            f"{kind:10s} wall median {mid:6.2f} s ({mid / median(wall[base]):4.2f}x)  "
            f"best {best:6.2f} s ({best / min(wall[base]):4.2f}x)  "
            f"own CPU median {used:5.2f} s ({used / median(own[base]):4.2f}x)  "
            f"children CPU median {child:5.2f} s"
        )


if __name__ == "__main__":
    main()
