"""The pty transport of the load-cell emulator: real time, meant to run in its own process.

`serve_loadcell` writes each sample's line to the master side of a `PtyPort` as its sample time
passes on `time.monotonic_ns`, until a `Stop` is set. Like a real device it never waits for
the host: when nobody reads and the pty buffer is full, lines are lost (counted). When the client
has configured a different baud rate than the device's, the client receives framing garbage, as
it would on a real UART, so a wrong `--baud` shows up as corrupt data rather than silence.

A client opening the port is the host opening it (`LoadCellEmulator.host_opened`): with a DTR
reset (`dtr_reset_s`) the board falls silent, then sends its banner and starts seq and its clock
from 0, as an Arduino does when pyserial asserts DTR. The open is seen through the pty's
`ClientOpens` watch (Linux inotify; rig/sim/pty_port.py), which also wakes the loop at once, so no
line of the old boot reaches the client after its open. Not verified against a real board.
"""

from __future__ import annotations

import os
import select
import time
from collections.abc import Callable
from dataclasses import dataclass

from rig.sim.loadcell.emulator import LoadCellEmulator, wrong_baud_garbage
from rig.sim.pty_port import ClientEvent, PtyPort, Stop

MAX_SLEEP_S = 0.05  # bounds how late a stop request is noticed
MIN_SLEEP_S = 0.0005
POLLED_MAX_SLEEP_S = 0.002  # a polled device must notice a poll soon after it arrives


@dataclass(slots=True)
class ServeCounts:
    """What the serve loop did."""

    lines_written: int = 0
    bytes_written: int = 0
    bytes_dropped: int = 0  # pty buffer full: nobody was reading
    wrong_baud_bytes: int = 0
    client_opens: int = 0  # a client opened the port (the board's DTR reset, if it has one)


def write_nonblocking(fd: int, data: bytes) -> int:
    """Write as much of `data` as fits now; return the number of bytes written."""
    written = 0
    view = memoryview(data)
    while written < len(data):
        try:
            n = os.write(fd, view[written:])
        except (BlockingIOError, InterruptedError):
            break
        if n <= 0:
            break
        written += n
    return written


def serve_loadcell(
    emulator: LoadCellEmulator,
    pty: PtyPort,
    stop: Stop,
    *,
    monotonic_ns: Callable[[], int] = time.monotonic_ns,
) -> ServeCounts:
    """Stream `emulator`'s lines to `link` in real time until `stop.stopped`."""
    counts = ServeCounts()
    opens = pty.client_opens()
    while not stop.stopped:
        for event in opens.events():
            if event is ClientEvent.OPENED:
                counts.client_opens += 1
                emulator.host_opened(monotonic_ns())
        now_ns = monotonic_ns()
        client_baud = pty.client_baud()  # one tcgetattr: cheap enough to follow the client closely
        lines = emulator.lines_until(now_ns)
        if lines:
            data = b"".join(chunk for _, chunk in lines)
            if client_baud is not None and client_baud != emulator.baud:
                data = wrong_baud_garbage(data)
                counts.wrong_baud_bytes += len(data)
            n = write_nonblocking(pty.master_fd, data)
            counts.bytes_written += n
            counts.bytes_dropped += len(data) - n
            counts.lines_written += len(lines)
        commands = pty.read()  # a streaming device ignores them; a polled one answers each poll
        if commands:
            emulator.receive(commands, monotonic_ns())
        wait_s = (emulator.next_sample_ns - monotonic_ns()) / 1e9
        longest_s = POLLED_MAX_SLEEP_S if emulator.poll_command is not None else MAX_SLEEP_S
        timeout_s = min(longest_s, max(MIN_SLEEP_S, wait_s))
        if opens.fd is not None:  # an open wakes the loop at once
            select.select([opens.fd], [], [], timeout_s)
        else:
            time.sleep(timeout_s)
    return counts
