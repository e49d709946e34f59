"""Pytest helpers for the Dynamixel emulator: a pty server subprocess that is always terminated.

Import the fixture into a test module with `from dxl_fixtures import dxl_server` (pytest puts
tests/ on sys.path), or call `servo_server(...)` as a context manager. The server is
`python -m rig.cli.sim_servos`, i.e. the same code as `rig sim servos`.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

STARTUP_TIMEOUT_S = 10.0
STOP_TIMEOUT_S = 5.0


@dataclass
class ServoServer:
    """A running `rig sim servos` process."""

    link: str
    pty: str
    process: subprocess.Popen[str]

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, str]:
        """Signal the server, wait (bounded) and return (exit code, stderr)."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        try:
            _, err = self.process.communicate(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            _, err = self.process.communicate(timeout=STOP_TIMEOUT_S)
        return self.process.returncode, err


@contextlib.contextmanager
def servo_server(
    link: str | os.PathLike[str],
    ids: Sequence[int] = (1,),
    *,
    baud: int = 1_000_000,
    model: str = "XM430-W350",
    faults: Sequence[str] = (),
    extra_args: Sequence[str] = (),
) -> Iterator[ServoServer]:
    """Start the server, wait for its `PTY ... LINK ...` line, and always terminate it on exit."""
    cmd = [
        sys.executable,
        "-m",
        "rig.cli.sim_servos",
        "--ids",
        ",".join(str(i) for i in ids),
        "--baud",
        str(baud),
        "--model",
        model,
        "--link",
        str(link),
        *(f"--fault={f}" for f in faults),
        *extra_args,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    server: ServoServer | None = None
    try:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        line = ""
        while not line:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or proc.poll() is not None:
                break
            ready, _, _ = select.select([proc.stdout], [], [], remaining)
            if ready:
                line = proc.stdout.readline()  # type: ignore[union-attr]
                if not line:
                    break
        words = line.split()
        if len(words) != 4 or words[0] != "PTY" or words[2] != "LINK":
            proc.kill()
            _, err = proc.communicate(timeout=STOP_TIMEOUT_S)
            raise RuntimeError(
                f"servo server did not start (line {line!r}, exit {proc.returncode}): {err.strip()}"
            )
        server = ServoServer(link=words[3], pty=words[1], process=proc)
        yield server
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=STOP_TIMEOUT_S)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


@pytest.fixture
def dxl_server(tmp_path: Path) -> Iterator[Callable[..., ServoServer]]:
    """Factory fixture: `dxl_server(ids=[1, 2], baud=57600, faults=[...])` -> a running `ServoServer`."""
    with contextlib.ExitStack() as stack:
        count = 0

        def start(**kwargs: object) -> ServoServer:
            nonlocal count
            count += 1
            return stack.enter_context(servo_server(tmp_path / f"dxl{count}", **kwargs))  # type: ignore[arg-type]

        yield start
