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

The servo's position resolution sets a second floor. The winch's goal is a whole number of counts
(XM430: 2π/4096 rad), so a line of stiffness k on a spool of radius r holds the tension only in
steps of q = k·r·2π/4096 (`count_n`: 77 mN on the simulated rig, 3 mN on the 200 N/m line of the
hardware template). Below one Profile Velocity unit the ramp steps the goal count by count; the
tension then rises in jumps of q with plateaus between them, and the slip comes during a jump: the
last sample before it reads a plateau, up to q below the slip load, however slowly the counts are
stepped. So a stepped ramp never goes slower than one count per sample period (`count_floor_rad_s`;
it binds at 10/s below 16 N on the simulated rig, where one count is more than the limit's share),
and the runner writes each step right after a sample (rig/runner/ramp.py), so that every plateau is
sampled. The error is then at most max(ε·P, q) (plus the cell's noise): below 0.5 % wherever
q < 0.5 % of the smallest slip load, which is a condition on the line, not on the ramp. A lab that
reads slip loads of P newtons needs k·r < 0.005·P·4096/(2π), e.g. k < 1800 N/m for 6 N on a 10 mm
spool (docs/hardware.md, "Line compliance and the slip load's resolution"). On hardware the
servo's profile moves in counts too, so q bounds the error at every speed; the simulator's profile
is continuous between counts (not verified on hardware).

The floor applies only below the expected slip load's range and in a trial with nothing to go on
(`counted`): inside the range, the ramp keeps the limit, because the faster re-tension of one
count per sample after a slip (1.3 % of a 6 N load per sample at 10/s) hid 3 % drops from the
detector in tests/test_rates.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rig.hw.dxl.units import RAD_PER_PULSE, RAD_S_PER_VELOCITY_UNIT

# The largest share of the slip load the sampling may cost (the target is 0.5 %; the rest is margin
# for the line's stiffness; the speed's steps stay below the limit).
SAMPLING_ERROR_FRACTION = 0.0047
# The low edge of the expected slip load is this many relative spreads below the prediction (the
# one-sided 99.5 % point of a normal spread).
BAND_Z = 2.576
# Where the sampling limit binds, the fast phase ends this many control ticks of full-speed rise
# below the capped ramp (at 10/s the winch overshot one tick's rise by up to 3 N onto the slip load).
APPROACH_TICKS = 3
# The relative spread (log sd) of a trial's slip load that a plan made before the run assumes for
# the trials after the first (`RampSpeeds.ramp_s`, `rig run --dry-run`): the simulated joints'
# trial-to-trial scatter (0.085) with the fit's own uncertainty.
PLANNED_SPREAD_LOG = 0.1
# The speed follows the limit in steps: it is rewritten when the limit has moved by this factor.
SPEED_STEP = 1.05


@dataclass(frozen=True)
class RampPlan:
    """Where one ramp changes speed.

    Attributes:
        arm_n: the detector's arm threshold (the slow phase's lowest tension for the limit).
        switch_n: the fast phase ends here.
        capped_n: the low edge of the expected slip load where the limit binds there (the fast phase
            ends short of it); the arm threshold with nothing to go on.
        read_ahead: the limit binds at the switch: between samples the runner reads the tension
            ahead from the winch's travel.
    """

    arm_n: float
    switch_n: float
    capped_n: float
    read_ahead: bool

    @property
    def expected(self) -> bool:
        """There is an expected range to go on (the count floor then applies only below it)."""
        return self.capped_n > self.arm_n


@dataclass(frozen=True)
class RampSpeeds:
    """The ramp's speeds for one rig and load cell.

    Attributes:
        fast_rad_s: the protocol's fast speed.
        slow_rad_s: the protocol's slow speed.
        rate_hz: the load cell's nominal sample rate.
        n_per_rad: the tension one radian of winch adds (nominal line stiffness × spool radius).
        count_rad: the winch servo's position resolution (one count).
    """

    fast_rad_s: float
    slow_rad_s: float
    rate_hz: float
    n_per_rad: float
    count_rad: float = RAD_PER_PULSE

    @property
    def count_n(self) -> float:
        """The tension one count of the winch adds: the finest step the tension can be held at."""
        return self.n_per_rad * self.count_rad

    @property
    def count_floor_rad_s(self) -> float:
        """One count per sample period where that is a stepped speed (below one velocity unit), else 0.

        Slower than that a stepped ramp reads the slip load no finer (see the module docstring).
        """
        floor = self.count_rad * self.rate_hz
        return floor if floor < RAD_S_PER_VELOCITY_UNIT else 0.0

    def limit_rad_s(self, force_n: float) -> float:
        """The fastest speed whose rise over one sample is `SAMPLING_ERROR_FRACTION` of `force_n`."""
        return SAMPLING_ERROR_FRACTION * force_n * self.rate_hz / self.n_per_rad

    def slow_at(self, force_n: float, floor_n: float, *, counted: bool = False) -> float:
        """The slow phase's speed at tension `force_n` (taken as at least `floor_n`, the arm threshold).

        `counted`: not slower than the count floor (`count_floor_rad_s`), as below the expected slip
        load's range and in a trial with nothing to go on.
        """
        limit = self.limit_rad_s(max(force_n, floor_n))
        return min(self.slow_rad_s, max(self.count_floor_rad_s, limit) if counted else limit)

    def binds_at(self, force_n: float) -> bool:
        """The sampling limit is below the protocol's slow speed at `force_n`."""
        return self.limit_rad_s(force_n) < self.slow_rad_s

    def slow_ramp_s(self, from_n: float, to_n: float, *, counted: bool = False) -> float:
        """Time the slow phase takes from `from_n` to `to_n` (both > 0) at `slow_at`.

        Up to three stretches, each where it applies: linear at the count floor (`counted`, where
        one count is more than the limit's share), exponential along the limit, linear at the
        protocol's slow speed.
        """
        if to_n <= from_n:
            return 0.0
        growth_per_s = SAMPLING_ERROR_FRACTION * self.rate_hz  # d(ln F)/dt along the limit
        floor_n_per_s = self.n_per_rad * min(self.count_floor_rad_s if counted else 0.0, self.slow_rad_s)
        slow_n_per_s = self.n_per_rad * self.slow_rad_s
        # The limit equals the floor at `floor_end_n` and the slow speed at `crossover_n`.
        crossover_n = slow_n_per_s / growth_per_s
        floor_end_n = min(floor_n_per_s / growth_per_s, crossover_n)
        seconds = 0.0
        if from_n < floor_end_n:
            seconds += (min(to_n, floor_end_n) - from_n) / floor_n_per_s
        low, high = max(from_n, floor_end_n), min(to_n, crossover_n)
        if high > low:
            seconds += math.log(high / low) / growth_per_s
        if to_n > crossover_n:
            seconds += (to_n - max(from_n, crossover_n)) / slow_n_per_s
        return seconds

    def plan(
        self,
        arm_n: float,
        predicted_n: float | None,
        expected_low_n: float | None,
        fast_until_fraction: float,
        control_period_s: float,
    ) -> RampPlan:
        """The ramp's plan for a trial whose slip is predicted at `predicted_n` (None: no prediction).

        The fast phase runs to `fast_until_fraction` of the prediction, or, where the limit binds at
        `expected_low_n` (the low edge of the expected slip load; None: not known), up to it, less
        what the winch reels at full speed in `APPROACH_TICKS` control ticks (it overshoots the
        switch by about that much): the slow phase, at the limit, covers that approach.
        """
        switch = arm_n
        if predicted_n is not None and math.isfinite(predicted_n):
            switch = max(switch, fast_until_fraction * predicted_n)
        read_ahead = self.binds_at(switch)
        capped = self.switch_n(switch, expected_low_n) if expected_low_n is not None else arm_n
        if capped > switch:
            approach_n = self.n_per_rad * self.fast_rad_s * APPROACH_TICKS * control_period_s
            switch = max(switch, capped - approach_n)
        return RampPlan(arm_n=arm_n, switch_n=switch, capped_n=max(capped, arm_n), read_ahead=read_ahead)

    def ramp_s(self, plan: RampPlan, slip_n: float) -> float:
        """Time a ramp takes from a taut line to a slip at `slip_n` under `plan`.

        Fast to the switch, then slow, with the count floor below the expected range (everywhere
        with nothing to go on). The winch's take-up of a slack line is left out.
        """
        fast_s = min(plan.switch_n, slip_n) / (self.n_per_rad * self.fast_rad_s)
        start = min(plan.switch_n, slip_n)
        if not plan.expected:
            return fast_s + self.slow_ramp_s(max(start, plan.arm_n), slip_n, counted=True)
        below = self.slow_ramp_s(start, min(slip_n, plan.capped_n), counted=True)
        return fast_s + below + self.slow_ramp_s(max(start, plan.capped_n), slip_n)

    def planned_ramp_s(
        self, arm_n: float, slip_n: float, first: bool, fast_until_fraction: float, control_period_s: float
    ) -> float:
        """`ramp_s` for a slip at `slip_n`, planned before the run.

        The first trial has nothing to go on; the others are predicted right, with a spread of
        `PLANNED_SPREAD_LOG`.
        """
        if first:
            plan = self.plan(arm_n, None, None, fast_until_fraction, control_period_s)
        else:
            low = slip_n * math.exp(-BAND_Z * PLANNED_SPREAD_LOG)
            plan = self.plan(arm_n, slip_n, low, fast_until_fraction, control_period_s)
        return self.ramp_s(plan, slip_n)

    def switch_n(self, switch_n: float, expected_low_n: float | None) -> float:
        """Where the fast phase ends: `switch_n`, or higher up to `expected_low_n` if the limit binds there.

        `expected_low_n` is the low edge of the expected slip load; the limit binds at low rates.
        """
        if expected_low_n is None or not math.isfinite(expected_low_n) or expected_low_n <= switch_n:
            return switch_n
        return expected_low_n if self.binds_at(expected_low_n) else switch_n
