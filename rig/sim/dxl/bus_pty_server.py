"""Serve an `EmulatedBus` on a pty in real time: the byte-for-byte path through pyserial and the real SDK.

Meant to run in its own process (`rig sim servos`): the SDK busy-spins a core while it waits, and
a reply must land inside its ~34 ms window, so the loop is lean: `poll` on the master fd, feed what
arrived to the bus with the monotonic time, write the replies. By default replies are written as
soon as they are computed (a pty does not throttle bytes, so pacing them by the simulated wire time
would only add latency); `wire_timing=True` holds each reply until its simulated due time. Injected
reply delays are always honoured. `usb_latency_s` emulates a USB-serial adapter's latency timer (an
FTDI chip such as the U2D2's holds a short reply until its timer expires: 16 ms by default on
Linux, 1 ms once set): every reply is held that long after it is computed, the worst case of a
timer that runs freely (a real chip's wait is between 0 and the timer); given as a callable it is
asked again for every chunk, so the emulated adapter follows its sysfs file as an FTDI chip follows
its own (`rig sim servos --sysfs-root`). The client's baud rate
is read from the pty on every chunk; servos at another rate (or a non-standard client rate) stay
silent, so baud scans are testable.
"""

from __future__ import annotations

import heapq
import select
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from rig.sim.dxl.emulated_bus import Reply
from rig.sim.pty_port import PtyPort, Stop

IDLE_POLL_MS = 50  # how often the loop looks at the stop flag when nothing happens


class ServedBus(Protocol):
    """What `serve` needs of a bus: the line rate to set, and bytes in, replies out."""

    baud: int

    def feed(self, data: bytes, now_ns: int) -> list[Reply]:
        """The replies to the bytes the host starts writing at `now_ns`."""
        ...


@dataclass(slots=True)
class ServeStats:
    """Counters of one serve session."""

    bytes_in: int = 0
    bytes_out: int = 0
    replies: int = 0
    chunks_ignored_for_baud: int = 0


def serve(
    bus: ServedBus,
    pty: PtyPort,
    stop: Stop,
    *,
    wire_timing: bool = False,
    usb_latency_s: float | Callable[[], float] = 0.0,
) -> ServeStats:
    """Answer the client on `link` until `stop.stopped`; returns the counters.

    `usb_latency_s` may be a callable, asked again at each chunk from the host: the latency timer as
    it is now (the emulated adapter's sysfs file, which a udev rule or a person may rewrite).
    """
    latency_of: Callable[[], float] = usb_latency_s if callable(usb_latency_s) else (lambda: usb_latency_s)
    latency_ns = round(latency_of() * 1e9)
    stats = ServeStats()
    poller = select.poll()
    poller.register(pty.master_fd, select.POLLIN)
    pending: list[tuple[int, int, bytes]] = []  # (monotonic due ns, seq, bytes)
    seq = 0
    monotonic_ns = time.monotonic_ns
    while not stop.stopped:
        wait_ms = max(0, (pending[0][0] - monotonic_ns()) // 1_000_000) if pending else IDLE_POLL_MS
        events = poller.poll(wait_ms)
        if events:
            data = pty.read()
            if data:
                now = monotonic_ns()
                latency_ns = round(latency_of() * 1e9)
                stats.bytes_in += len(data)
                baud = pty.client_baud()
                if baud is None:
                    stats.chunks_ignored_for_baud += 1
                else:
                    bus.baud = baud
                    for reply in bus.feed(data, now):
                        due = (reply.due_ns if wire_timing else now + reply.extra_delay_ns) + latency_ns
                        if due <= now and not pending:
                            pty.write(reply.data)
                            stats.bytes_out += len(reply.data)
                            stats.replies += 1
                        else:
                            seq += 1
                            heapq.heappush(pending, (due, seq, reply.data))
            elif events[0][1] & (select.POLLHUP | select.POLLERR):
                time.sleep(0.001)  # no client side open; do not spin
        if pending:
            now = monotonic_ns()
            while pending and pending[0][0] <= now:
                out = heapq.heappop(pending)[2]
                pty.write(out)
                stats.bytes_out += len(out)
                stats.replies += 1
    return stats
