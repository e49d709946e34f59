"""The online joint-estimation fit: a pure step function over (distance, mass) pairs, O(1) per update.

The state is the fit's sufficient statistics (n, Σx², Σxm, Σm², Σm with x = 1/l) held **exactly**
as scaled Python ints (`model.fit.ExactSums`): no rounding ever enters the accumulators, so there is
nothing to cancel catastrophically when R² → 1 or the masses barely vary, whatever the scale of the
data. The estimate is evaluated by the very evaluator the batch fit uses (`model.fit.fit_from_sums`),
so after every update it equals `fit_inverse_distance` of all the data so far, bit for bit.

Cost per update: one exact float-to-int conversion per value and three multiplications of ints of
about 1100 bits (an int grows by one bit per doubling of n), independent of how many pairs came
before; no data are stored. Measured in `benchmarks/bench_online_fit.py`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from model.fit import DEFAULT_LEVEL, ExactSums, InverseFit, check_level, check_pair, fit_from_sums


@dataclass(frozen=True)
class OnlineFitState:
    """Everything the online fit remembers: the exact sums of all pairs seen so far."""

    sums: ExactSums = field(default_factory=ExactSums)

    @property
    def n(self) -> int:
        """Number of pairs seen so far."""
        return self.sums.n


def online_fit_init() -> OnlineFitState:
    """The state before any pair has been seen."""
    return OnlineFitState()


def online_fit_update(state: OnlineFitState, distance_m: float, mass_kg: float) -> OnlineFitState:
    """The state after one more slip trial: mass `mass_kg` [kg] slipped the joint at `distance_m` [m].

    Raises ValueError for a distance that is not finite and > 0, or a non-finite mass; the state
    passed in is left as it was (it is immutable).
    """
    distance, mass = check_pair(distance_m, mass_kg)
    return OnlineFitState(state.sums.add(1.0 / distance, mass))


def online_fit_estimate(state: OnlineFitState, level: float = DEFAULT_LEVEL) -> InverseFit | None:
    """The fit of every pair seen so far, or None while fewer than 2 pairs have been seen."""
    level = check_level(level)
    if state.sums.n < 2:
        return None
    return fit_from_sums(state.sums, level)
