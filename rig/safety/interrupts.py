"""Holding Ctrl-C (and SIGTERM) back while the rig is being made safe.

What this module owns: the one implementation of signal deferral. `signals_deferred` remembers
the given signals instead of acting on them for the duration of a block and tells the caller
which came; `interrupts_deferred` is the runner's form, which re-raises them as KeyboardInterrupt
once the block is done. The servo bus uses the first around its torque-off, the runner the second
around its release/torque-off/flush sequence, so a second Ctrl-C cannot leave the torque on.
Signal handlers can be set only from the main thread; elsewhere both are no-ops.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any


@contextmanager
def signals_deferred(*signums: int) -> Iterator[list[int]]:
    """Remember `signums` instead of handling them until the block ends; yields the ones received.

    The previous handlers are restored on exit; the caller decides what a received signal means.
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def remember(signum: int, frame: FrameType | None) -> None:
        received.append(signum)

    previous: dict[int, Any] = {}
    try:
        for signum in signums:
            previous[signum] = signal.signal(signum, remember)
    except ValueError:  # pragma: no cover - no signal support here: defer what could be deferred
        pass
    try:
        yield received
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Defer SIGINT/SIGTERM until the block ends, then raise KeyboardInterrupt if one came."""
    with signals_deferred(signal.SIGINT, signal.SIGTERM) as received:
        yield
    if received:
        raise KeyboardInterrupt
