"""What each simulated loading draws: its capacity factors and its slip kind with parameters.

Two random streams of the seed (`article_presets.STREAM_TRIAL_CAPACITY`, `STREAM_SLIP_KIND`), one
draw sequence per trial each, in a fixed order (a change of order changes every later trial):

* **Capacities.** Each joint of the hooked article gets an independent factor 1 + s·z, z ~ N(0, 1)
  clipped at ±3 (floored at `MIN_CAPACITY_FACTOR`), where for a slip mass m of that joint
  s = sqrt((a/m)² + b²), so that sd(m)² = a² + (b·m)²: multiplicative scatter has a = 0 and s = b,
  additive b = 0; m is the joint's capacity over g times its lever arm in the configuration at the
  trial's start (for the specimen, the hook distance).
* **Slip kind.** One uniform number picks the kind from the preset's `slip_mix`, then the kind's
  parameters are drawn uniformly from their ranges (`SlipKindMix` documents them).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import assert_never

import numpy as np

from rig.sim.kinds import SlipKind
from rig.sim.physics.link import ChainLink
from rig.sim.physics.link_presets import STREAM_SLIP_KIND, STREAM_TRIAL_CAPACITY, SimPreset, stream_rng
from rig.sim.truth import SlipPlan

MIN_CAPACITY_FACTOR = 0.05


@dataclass(frozen=True)
class CapacityDraw:
    """One trial's capacity factors and the relative sd s of each."""

    factors: np.ndarray
    relative_sds: np.ndarray


@dataclass(frozen=True)
class TrialDraw:
    """What one loading drew: its capacity factors and its slip plan (loads scaled to the article)."""

    capacity: CapacityDraw
    plan: SlipPlan


class TrialDraws:
    """The per-trial random draws of a seeded world (each on its own stream)."""

    def __init__(self, preset: SimPreset, seed: int) -> None:
        self.preset = preset
        self._capacity_rng = stream_rng(seed, STREAM_TRIAL_CAPACITY)
        self._kind_rng = stream_rng(seed, STREAM_SLIP_KIND)

    def draw(self, article: ChainLink, *, joint_estimation: bool, specimen_joint: int | None) -> TrialDraw:
        """Draw a loading's capacities, set them on `article` as it is posed now, and its slip plan.

        The specimen (joint estimation) is joint `specimen_joint` of the link, or the preset's
        nominal joint; the link's joints are the preset's.
        """
        preset = self.preset
        if not joint_estimation:
            nominal = np.asarray(preset.joint_capacities_nm)
        elif specimen_joint is None:
            nominal = np.array([preset.specimen_capacity_nm])
        else:
            nominal = np.array([preset.joint_capacities_nm[specimen_joint - 1]])
        capacity = self.capacity_factors(nominal, article)
        plan = self.slip_plan(joint_estimation, specimen_joint)
        capacities = nominal * capacity.factors
        if plan.kind == SlipKind.NO_SLIP:
            capacities = capacities * preset.slip_mix.no_slip_capacity_factor
        article.set_capacities(capacities)
        if plan.kind == SlipKind.OTHER_JOINT:
            assert plan.other_load_n is not None
            # The fraction drawn becomes a load (inf if the specimen cannot slip).
            plan = replace(plan, other_load_n=plan.other_load_n * article.slip_threshold_n)
        return TrialDraw(capacity, plan)

    def capacity_factors(self, nominal_nm: np.ndarray, article: ChainLink) -> CapacityDraw:
        """Factors for the capacities `nominal_nm` of the joints of `article` as it is posed now."""
        preset = self.preset
        draws = np.clip(self._capacity_rng.standard_normal(len(nominal_nm)), -3.0, 3.0)
        if preset.scatter_a_kg == 0:
            relative_sds = np.full(len(nominal_nm), preset.per_trial_capacity_sd)
            factors = np.maximum(1.0 + preset.per_trial_capacity_sd * draws, MIN_CAPACITY_FACTOR)
        else:
            # sd(m)/m with m = capacity / (g · lever arm): a·g·arm/capacity for the additive part.
            arms = np.asarray(article.lever_arms_m()[1:])
            additive = preset.scatter_a_kg * preset.g * arms / nominal_nm
            relative_sds = np.sqrt(additive**2 + preset.per_trial_capacity_sd**2)
            factors = np.maximum(1.0 + relative_sds * draws, MIN_CAPACITY_FACTOR)
        return CapacityDraw(factors, relative_sds)

    def slip_plan(self, joint_estimation: bool, specimen_joint: int | None) -> SlipPlan:
        """The trial's slip kind and its parameters.

        For `other_joint` (joint estimation only; link validation makes it sudden, still drawn),
        `other_load_n` is the fraction of the slip load: the world scales it.
        """
        mix = self.preset.slip_mix
        rng = self._kind_rng
        u = float(rng.random())
        cumulative = np.cumsum(mix.probabilities)
        index = min(int(np.searchsorted(cumulative, u, side="right")), len(SlipKind) - 1)
        while mix.probabilities[index] == 0:  # u at the very top of the range: the last kind that can occur
            index -= 1
        slip_kind = list(SlipKind)[index]

        def uniform(bounds: tuple[float, float]) -> float:
            return float(rng.uniform(bounds[0], bounds[1]))

        match slip_kind:
            case SlipKind.SUDDEN | SlipKind.NO_SLIP:
                return SlipPlan(slip_kind)
            case SlipKind.SMALL_DROP:
                return SlipPlan(slip_kind, drop_fraction=uniform(mix.small_drop_fraction))
            case SlipKind.CREEP:
                return SlipPlan(
                    slip_kind,
                    creep_duration_s=uniform(mix.creep_duration_s),
                    creep_drop_fraction=uniform(mix.creep_drop_fraction),
                )
            case SlipKind.STICK_SLIP:
                low, high = (int(x) for x in mix.stick_slip_drops)
                drops = int(rng.integers(low, high + 1))
                return SlipPlan(
                    slip_kind,
                    drop_fraction=uniform(mix.stick_slip_drop_fraction),
                    train_drops=drops,
                    dwells_s=tuple(uniform(mix.stick_slip_dwell_s) for _ in range(drops - 1)),
                )
            case SlipKind.OTHER_JOINT:
                if not joint_estimation:
                    return SlipPlan(SlipKind.SUDDEN)  # every joint of the link is under test
                specimen = 1 if specimen_joint is None else specimen_joint
                count = self.preset.joint_count
                # The next joint out, or the one before the last (0: the clamp of a 1-joint link).
                neighbour = specimen + 1 if specimen < count else specimen - 1
                return SlipPlan(
                    slip_kind,
                    other_joint=neighbour,
                    other_load_n=uniform(mix.other_joint_load_fraction),
                    drop_fraction=uniform(mix.other_joint_drop_fraction),
                )
            case _:
                assert_never(slip_kind)
