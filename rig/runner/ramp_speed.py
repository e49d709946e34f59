"""How fast the winch may load the line at the load cell's sample rate: the sampling error of the slip load.

The detector reads the slip load as the highest sample before the drop. The true peak comes between
two samples, so the last sample before the slip is below it by up to the tension's rise over one
sample period: the ramp rate R [N/s] times T = 1/rate. To keep that share of the slip load P below
`SAMPLING_ERROR_FRACTION` (ε), R ≤ ε·P/T; and since the tension F is at most P until the slip, a ramp
rate of ε·F/T at every F keeps it wherever the slip comes. In winch speed that is ε·F·rate/(k·r),
k the rig's nominal line stiffness and r the spool radius (a line stiffer than its nominal value
raises the error in proportion).

With the simulated rig (5000 N/m, 10 mm spool) at 1000 samples/s the limit is 0.094·F rad/s, above
the protocols' slow speeds from 1 N on: the ramp is the protocol's. At 80/s it binds below 11 N, at
10/s below 85 N (100 times slower than at 1000/s): there the tension rises by ε of itself per
sample, exponentially, and crossing a band of loads from F₁ to F₂ takes ln(F₂/F₁)/(ε·rate) s
(21 s per e-fold at 10/s). So the ramp is slow only where the slip is expected: it reels fast up to
the larger of `fast_until_fraction` × the prediction and the low edge of the slip load's expected
range (`RunEstimator.joint_estimation_force_low_n`, `BAND_Z` spreads below the prediction), then
follows the limit. A trial with nothing to go on (the first one) is slow, at the limit, from the
detector's arm threshold: the documented conservative speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# The largest share of the slip load the sampling may cost (the target is 0.5 %; the rest is margin
# for the line's stiffness; the speed's steps stay below the limit).
SAMPLING_ERROR_FRACTION = 0.0047
# The low edge of the expected slip load is this many relative spreads below the prediction (the
# one-sided 99.5 % point of a normal spread).
BAND_Z = 2.576
# The speed follows the limit in steps: it is rewritten when the limit has moved by this factor.
SPEED_STEP = 1.05


@dataclass(frozen=True)
class RampSpeeds:
    """The ramp's speeds for one rig and load cell.

    Attributes:
        fast_rad_s: the protocol's fast speed.
        slow_rad_s: the protocol's slow speed.
        rate_hz: the load cell's nominal sample rate.
        n_per_rad: the tension one radian of winch adds (nominal line stiffness × spool radius).
    """

    fast_rad_s: float
    slow_rad_s: float
    rate_hz: float
    n_per_rad: float

    def limit_rad_s(self, force_n: float) -> float:
        """The fastest speed whose rise over one sample is `SAMPLING_ERROR_FRACTION` of `force_n`."""
        return SAMPLING_ERROR_FRACTION * force_n * self.rate_hz / self.n_per_rad

    def slow_at(self, force_n: float, floor_n: float) -> float:
        """The slow phase's speed at tension `force_n` (taken as at least `floor_n`, the arm threshold)."""
        return min(self.slow_rad_s, self.limit_rad_s(max(force_n, floor_n)))

    def binds_at(self, force_n: float) -> bool:
        """The sampling limit is below the protocol's slow speed at `force_n`."""
        return self.limit_rad_s(force_n) < self.slow_rad_s

    def slow_ramp_s(self, from_n: float, to_n: float) -> float:
        """Time the slow phase takes from `from_n` to `to_n` (both > 0): exponential, then linear."""
        if to_n <= from_n:
            return 0.0
        crossover_n = self.slow_rad_s * self.n_per_rad / (SAMPLING_ERROR_FRACTION * self.rate_hz)
        seconds = 0.0
        if from_n < crossover_n:
            seconds += math.log(min(to_n, crossover_n) / from_n) / (SAMPLING_ERROR_FRACTION * self.rate_hz)
        if to_n > crossover_n:
            seconds += (to_n - max(from_n, crossover_n)) / (self.n_per_rad * self.slow_rad_s)
        return seconds

    def switch_n(self, switch_n: float, expected_low_n: float | None) -> float:
        """Where the fast phase ends: `switch_n`, or higher up to `expected_low_n` if the limit binds there.

        `expected_low_n` is the low edge of the expected slip load; the limit binds at low rates.
        """
        if expected_low_n is None or not math.isfinite(expected_low_n) or expected_low_n <= switch_n:
            return switch_n
        return expected_low_n if self.binds_at(expected_low_n) else switch_n
