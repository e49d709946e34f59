"""The run's trial sequence: fixed trials as planned, adaptive blocks one trial at a time.

`TrialSchedule` is what `TrialRunner.run` iterates over. Fixed trials not yet in the journal come
as the protocol planned them. For a `design: adaptive` block it asks `model.design.plan_next`, before
every trial, for the next distance, from the block's results **in the journal** (the runner journals
each trial before it asks for the next one): so a resumed run replans from exactly the results the
interrupted one had, and a block that had already stopped stops again at once. After every trial of
such a block it reports, on `/rig/log` and the progress display, the estimate, the lack-of-fit test
of the 1/l law, and the next distance or why the block stopped (target reached, budget used, no
safe distance); `summaries` keeps the last report of each block for the run's report.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any

from model.design import DesignStep, Observation, StopReason, current_estimate, plan_next
from rig.inputs.protocol import AdaptiveBlock, Protocol, TrialPlan
from rig.inputs.rig_config import RigConfig
from rig.records import TrialOutcome, TrialResult
from rig.runner.journal import RunJournal
from rig.runner.limits import max_slip_force_n

# announce(text, warning): a line for the log and the progress display.
Announce = Callable[[str, bool], None]


@dataclass(frozen=True, slots=True)
class AdaptiveSummary:
    """Where an adaptive block stands after its latest trial (the `design` entries of `rig run --json`)."""

    block: int
    joint: int
    estimator: str
    step: DesignStep
    target_half_width_rel: float
    max_trials: int
    text: str  # the line logged and shown for it

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this block's state."""
        step = self.step
        test = step.lack_of_fit
        estimate = step.estimate
        return {
            "block": self.block,
            "joint": self.joint,
            "estimator": self.estimator,
            "scatter_model": estimate.scatter_model if estimate is not None else None,
            "trials": step.trials_done,
            "max_trials": self.max_trials,
            "stop_reason": step.stop.value if step.stop is not None else None,
            "half_width_rel": step.half_width_rel,
            "stop_half_width_rel": step.stop_half_width_rel,
            "target_half_width_rel": self.target_half_width_rel,
            "next_distance_m": step.next_distance_m,
            "lack_of_fit": {
                "test": test.test,
                "statistic": _finite(test.statistic),
                "df": list(test.df),
                "p_value": _finite(test.p_value),
                "rejected": test.rejected,
                "distinct_distances": test.distinct_distances,
            },
        }


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def observations(block: AdaptiveBlock, results: list[TrialResult]) -> list[Observation]:
    """The block's slips, and its no-slips as lower bounds, in the order run."""
    found = []
    for r in results:
        if r.trial_id not in block.trial_ids or r.distance_m is None or r.slip_mass_kg is None:
            continue
        if r.outcome == TrialOutcome.SLIP:
            found.append(Observation(r.distance_m, r.slip_mass_kg))
        elif r.outcome == TrialOutcome.NO_SLIP:
            found.append(Observation(r.distance_m, r.slip_mass_kg, censored=True))
    return found


class TrialSchedule:
    """The remaining trials of a run, in order; iterate once (see the module docstring)."""

    def __init__(
        self,
        protocol: Protocol,
        config: RigConfig,
        journal: RunJournal,
        announce: Announce | None = None,
    ) -> None:
        self.protocol = protocol
        self.config = config
        self.journal = journal
        self.announce: Announce = announce or (lambda text, warning: None)
        self.summaries: dict[int, AdaptiveSummary] = {}

    def __iter__(self) -> Iterator[TrialPlan]:
        for item in self.protocol.schedule:
            if isinstance(item, TrialPlan):
                if item.trial_id not in self.journal.completed_ids:
                    yield item
            else:
                yield from self._adaptive(item)

    def plan(self, block: AdaptiveBlock) -> DesignStep:
        """The planner's step for `block` after the results journalled so far."""
        found = observations(block, self.journal.completed)
        return plan_next(
            block.design,
            found,
            current_estimate(block.design, found),
            max_slip_force_n=max_slip_force_n(block, self.protocol, self.config),
            g=self.config.article.g,
        )

    def _adaptive(self, block: AdaptiveBlock) -> Iterator[TrialPlan]:
        while True:
            step = self.plan(block)
            used = [r for r in self.journal.completed if r.trial_id in block.trial_ids]
            next_id = block.first_trial_id + len(used)
            if step.stop is None and next_id not in block.trial_ids:
                # Trials that ended without data for the fit (aborted ones) used up the block's ids.
                step = replace(
                    step,
                    next_distance_m=None,
                    choice=None,
                    expected_half_width_rel=None,
                    stop=StopReason.BUDGET,
                )
            self._report(block, step)
            if step.stop is not None or step.next_distance_m is None:
                return
            repeat = 1 + sum(1 for r in used if r.distance_m == step.next_distance_m)
            yield block.trial(next_id, step.next_distance_m, repeat)

    def _report(self, block: AdaptiveBlock, step: DesignStep) -> None:
        design = block.design
        text = f"adaptive design, block {block.block} (joint {block.joint}): {step.text(design)}"
        self.summaries[block.block] = AdaptiveSummary(
            block.block,
            block.joint,
            design.estimator,
            step,
            design.target_half_width_rel,
            design.max_trials,
            text,
        )
        self.announce(text, step.lack_of_fit.rejected)
