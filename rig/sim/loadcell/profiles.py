"""Scripted line-tension profiles for the load-cell emulator when no simulated world drives it.

`rig sim loadcell` uses these so that a person watching a serial monitor sees something
meaningful. The default `sawtooth` repeats a slip trial in miniature: the tension ramps linearly
from 0 to the peak, drops in one sample to 30 % of the peak (a slip: the line slackens), decays to
zero and rests, so every period shows a ramp, a sudden drop and a quiet zero stretch to tare on.
`StepTension` is a settable constant for procedures driven from code (calibration in simulation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rig.errors import InputError

SLIP_DROP_FRACTION = 0.3  # tension right after a slip, as a fraction of the peak
MAX_TENSION_N = 1e4  # |tension| of a profile
PERIOD_RANGE_S = (0.01, 1e6)


@dataclass(frozen=True, slots=True)
class ConstantTension:
    """The same tension at every instant."""

    tension_n: float

    def __call__(self, t_ns: int) -> float:
        """Tension at monotonic time `t_ns`."""
        return self.tension_n


@dataclass(frozen=True, slots=True)
class SawtoothTension:
    """Ramp 0 -> peak over 70 % of the period, drop to 30 % of peak, decay, rest at zero."""

    peak_n: float = 20.0
    period_s: float = 4.0
    start_ns: int = 0

    def __call__(self, t_ns: int) -> float:
        """Tension at monotonic time `t_ns`."""
        phase = ((t_ns - self.start_ns) / 1e9 % self.period_s) / self.period_s
        if phase < 0.7:
            return self.peak_n * phase / 0.7
        if phase < 0.85:
            # After the slip: the slack line's tension decays from 30 % of the peak towards zero.
            return self.peak_n * SLIP_DROP_FRACTION * math.exp(-(phase - 0.7) / 0.03)
        return 0.0


class StepTension:
    """A tension that code sets; after each change it rings (3 Hz, decaying in 0.3 s) like a hung mass."""

    RING_HZ = 3.0
    RING_DECAY_S = 0.3
    RING_FRACTION = 0.05

    def __init__(self, tension_n: float = 0.0) -> None:
        self._from_n = tension_n
        self._to_n = tension_n
        self._since_ns: int | None = None

    def set(self, tension_n: float, at_ns: int) -> None:
        """Change to `tension_n` at monotonic time `at_ns`."""
        self._from_n, self._to_n, self._since_ns = self._to_n, tension_n, at_ns

    def __call__(self, t_ns: int) -> float:
        """Tension at monotonic time `t_ns`."""
        if self._since_ns is None or t_ns < self._since_ns:
            return self._from_n if self._since_ns is not None else self._to_n
        dt_s = (t_ns - self._since_ns) / 1e9
        step = self._to_n - self._from_n
        ring = self.RING_FRACTION * step * math.exp(-dt_s / self.RING_DECAY_S)
        return self._to_n + ring * math.sin(2 * math.pi * self.RING_HZ * dt_s)


def parse_profile(spec: str, start_ns: int = 0) -> ConstantTension | SawtoothTension:
    """`constant:N` or `sawtooth[:PEAK_N[:PERIOD_S]]` -> a tension callable."""
    kind, _, rest = spec.partition(":")
    parts = [p for p in rest.split(":") if p] if rest else []
    lo, hi = PERIOD_RANGE_S
    try:
        if kind == "constant" and len(parts) == 1:
            tension = float(parts[0])
            if abs(tension) <= MAX_TENSION_N:
                return ConstantTension(tension)
        if kind == "sawtooth" and len(parts) <= 2:
            peak = float(parts[0]) if parts else 20.0
            period = float(parts[1]) if len(parts) > 1 else 4.0
            if lo <= period <= hi and abs(peak) <= MAX_TENSION_N:
                return SawtoothTension(peak, period, start_ns)
    except ValueError:
        pass
    raise InputError(
        f"--profile {spec!r}; allowed: constant:TENSION_N or sawtooth[:PEAK_N[:PERIOD_S]], "
        f"|tension| <= {MAX_TENSION_N:g} N, period {lo:g}-{hi:g} s"
    )
