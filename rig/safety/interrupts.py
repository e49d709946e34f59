"""Holding Ctrl-C (and SIGTERM) back while the rig is being made safe.

What this module owns: the one implementation of signal deferral and its three forms.
`signals_deferred` remembers the given signals instead of acting on them for the duration of a
block and tells the caller which came. `interrupts_deferred` re-raises them as KeyboardInterrupt
once the block is done: the servo bus uses the first around its torque-off, the runner the second
around its release/torque-off/flush sequence, so a second Ctrl-C cannot leave the line under
tension or the torque on. `interrupts_held` defers them the same way but drops them after the
block: for the end of a run, which must go on to write its journal and report (docs/design.md §6).
`terminate_as_interrupt` makes a `kill` end the run the same way as Ctrl-C.
Signal handlers can be set only from the main thread; elsewhere all of them are no-ops.
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


@contextmanager
def interrupts_held() -> Iterator[list[int]]:
    """Defer SIGINT/SIGTERM until the block ends and do not raise then; yields the ones received.

    For work that ends a run once its outcome is decided (the safe state, the log, the journal, the
    report): an interrupt arriving then has nothing left to stop.
    """
    with signals_deferred(signal.SIGINT, signal.SIGTERM) as received:
        yield received


def terminate_as_interrupt() -> None:
    """Make SIGTERM behave like Ctrl-C for the run (so a `kill` also ends in the safe state)."""
    if threading.current_thread() is threading.main_thread():

        def raise_interrupt(signum: int, frame: FrameType | None) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, raise_interrupt)
