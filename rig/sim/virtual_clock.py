"""Virtual time: a clock that advances only when asked, so simulations run as fast as the CPU allows.

Everything simulated (world physics, servo and load-cell emulators) and the runner share one
`VirtualClock`. Listeners registered with `on_advance` are called, in registration order, with the
new time after every advance; the simulated world uses this to integrate up to "now".
"""

from __future__ import annotations

from collections.abc import Callable

DEFAULT_EPOCH_NS = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z: reproducible log times


class VirtualClock:
    """A monotonic clock in integer nanoseconds that `sleep` and `advance_ns` move forward."""

    def __init__(self, epoch_ns: int = DEFAULT_EPOCH_NS) -> None:
        self._now_ns = 0
        self._epoch_ns = epoch_ns
        self._listeners: list[Callable[[int], None]] = []

    def monotonic_ns(self) -> int:
        """Virtual nanoseconds since the clock was made."""
        return self._now_ns

    def time_ns(self) -> int:
        """Virtual epoch nanoseconds."""
        return self._epoch_ns + self._now_ns

    def sleep(self, seconds: float) -> None:
        """Advance by `seconds` instead of waiting."""
        if seconds > 0:
            self.advance_ns(round(seconds * 1e9))

    def advance_ns(self, dt_ns: int) -> None:
        """Move time forward by `dt_ns` (>= 0) and notify the listeners."""
        if dt_ns < 0:
            raise ValueError(f"virtual time cannot go backwards (asked {dt_ns} ns)")
        if dt_ns == 0:
            return
        self._now_ns += dt_ns
        for listener in self._listeners:
            listener(self._now_ns)

    def advance_to_ns(self, t_ns: int) -> None:
        """Move time forward to monotonic `t_ns` if it is in the future."""
        if t_ns > self._now_ns:
            self.advance_ns(t_ns - self._now_ns)

    def on_advance(self, listener: Callable[[int], None]) -> None:
        """Call `listener(now_monotonic_ns)` after every advance."""
        self._listeners.append(listener)
