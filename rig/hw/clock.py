"""The real-time clock: `time.monotonic_ns` for intervals plus one epoch anchor per run."""

from __future__ import annotations

import time


class SystemClock:
    """Real time. Epoch times are the monotonic clock shifted by an anchor taken once."""

    def __init__(self) -> None:
        self._anchor_mono_ns = time.monotonic_ns()
        self._anchor_epoch_ns = time.time_ns()

    def monotonic_ns(self) -> int:
        """Nanoseconds on the host's monotonic clock."""
        return time.monotonic_ns()

    def time_ns(self) -> int:
        """Epoch nanoseconds derived from the monotonic clock, so they never go backwards."""
        return self._anchor_epoch_ns + (time.monotonic_ns() - self._anchor_mono_ns)

    def sleep(self, seconds: float) -> None:
        """Sleep for real."""
        if seconds > 0:
            time.sleep(seconds)
