"""Keeping Ctrl-C from skipping the safe-state sequence.

`interrupts_deferred()` (defined in `rig.hw.interrupts`, shared with the servo bus) wraps the
release/torque-off/flush sequence: a SIGINT (or SIGTERM) arriving inside it is remembered, not
raised, and re-raised as KeyboardInterrupt once the block is done. A second Ctrl-C therefore cannot
leave the line under tension or the torque on. `terminate_as_interrupt()` makes a `kill` end the
run the same way.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType

from rig.hw.interrupts import interrupts_deferred

__all__ = ["interrupts_deferred", "terminate_as_interrupt"]


def terminate_as_interrupt() -> None:
    """Make SIGTERM behave like Ctrl-C for the run (so a `kill` also ends in the safe state)."""
    if threading.current_thread() is threading.main_thread():

        def raise_interrupt(signum: int, frame: FrameType | None) -> None:
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, raise_interrupt)
