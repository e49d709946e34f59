"""The line tension the world recorded at each substep, kept for the last seconds and read back in between.

The load cells sample it (`at`, or `at_many` for a tick's batch of sample times): a time later than
the last entry reads the last value, a time in between interpolates linearly, and a time older than
the retained history is a `ValueError`. The history keeps `keep` entries at least and is trimmed in
place, in one go, once it holds twice as many.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence


class TensionHistory:
    """Recorded (time [ns, monotonic], tension [N]) pairs in ascending time."""

    def __init__(self, keep: int, t_ns: int, tension_n: float) -> None:
        self.keep = int(keep)
        self.times_ns: list[int] = [t_ns]
        self.tensions_n: list[float] = [tension_n]

    @property
    def last_n(self) -> float:
        """The most recently recorded tension [N]."""
        return self.tensions_n[-1]

    def record(self, t_ns: int, tension_n: float) -> None:
        """Append the tension at `t_ns` (not earlier than the last entry)."""
        self.times_ns.append(t_ns)
        self.tensions_n.append(tension_n)
        if len(self.times_ns) > 2 * self.keep:
            self.trim()

    def trim(self) -> None:
        """Keep the last `keep` entries (in place: the lists stay the same objects)."""
        drop = len(self.times_ns) - self.keep
        del self.times_ns[:drop]
        del self.tensions_n[:drop]

    def at(self, t_ns: int) -> float:
        """Tension [N] at monotonic `t_ns`, linearly interpolated; later than the history: the last value."""
        times = self.times_ns
        if t_ns >= times[-1]:
            return self.tensions_n[-1]
        if t_ns < times[0]:
            raise ValueError(f"t_ns = {t_ns} is older than the tension history (from {times[0]} ns)")
        i = bisect.bisect_right(times, t_ns)
        t0, t1 = times[i - 1], times[i]
        f0, f1 = self.tensions_n[i - 1], self.tensions_n[i]
        return f0 + (f1 - f0) * (t_ns - t0) / (t1 - t0)

    def at_many(self, times_ns: Sequence[int]) -> list[float]:
        """`at` of each of the ascending `times_ns` (one batch: a load cell's samples of a tick).

        Fast path of `[self.at(t) for t in times_ns]` with the same arithmetic, found by walking the
        history once instead of bisecting per time (tests/test_sim_fast_paths.py holds them equal).
        """
        times, tensions = self.times_ns, self.tensions_n
        if not times_ns:
            return []
        last_t = times[-1]
        first = times_ns[0]
        if first < times[0]:
            raise ValueError(f"t_ns = {first} is older than the tension history (from {times[0]} ns)")
        out: list[float] = []
        i = bisect.bisect_right(times, first) if first < last_t else len(times)
        count = len(times)
        for t_ns in times_ns:
            if t_ns >= last_t:
                out.append(tensions[-1])
                continue
            while i < count and times[i] <= t_ns:
                i += 1
            t0, t1 = times[i - 1], times[i]
            f0, f1 = tensions[i - 1], tensions[i]
            out.append(f0 + (f1 - f0) * (t_ns - t0) / (t1 - t0))
        return out
