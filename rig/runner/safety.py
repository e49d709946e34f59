"""Keeping Ctrl-C from skipping the safe-state sequence.

`interrupts_deferred()` (defined in `rig.safety.interrupts`, shared with the servo bus) wraps the
release/torque-off/flush sequence: a SIGINT (or SIGTERM) arriving inside it is remembered, not
raised, and re-raised as KeyboardInterrupt once the block is done. A second Ctrl-C therefore cannot
leave the line under tension or the torque on. `interrupts_held()` defers them the same way but
drops them after the block: for the end of a run, which must go on to write its journal and report
(docs/design.md §6). `terminate_as_interrupt()` makes a `kill` end the run the same way as Ctrl-C.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

from rig.safety.interrupts import interrupts_deferred, signals_deferred

__all__ = ["interrupts_deferred", "interrupts_held", "terminate_as_interrupt"]


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
