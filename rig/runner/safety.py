"""Keeping Ctrl-C from skipping the safe-state sequence.

`interrupts_deferred()` wraps the release/torque-off/flush sequence: a SIGINT (or SIGTERM)
arriving inside it is remembered, not raised, and re-raised as KeyboardInterrupt once the block is
done. A second Ctrl-C therefore cannot leave the line under tension or the torque on.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Defer SIGINT/SIGTERM until the block ends (no-op outside the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def remember(signum: int, frame: FrameType | None) -> None:
        received.append(signum)

    previous: dict[int, Any] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, remember)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if received:
        raise KeyboardInterrupt


def terminate_as_interrupt() -> None:
    """Make SIGTERM behave like Ctrl-C for the run (so a `kill` also ends in the safe state)."""
    if threading.current_thread() is threading.main_thread():

        def raise_interrupt(signum: int, frame: FrameType | None) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, raise_interrupt)
