"""A run's estimation series: the fixed trials per joint, and each adaptive block on its own.

A study scores one case per series. The fixed joint-estimation trials of a joint form one series
(as they always have). An adaptive block is a series of its own, scored on its own trials only:
its planner stopped on those (`rig.runner.planning.observations`), so the bound it stopped on is
the one the study checks, and a fixed block on the same joint does not blur it. Its case carries
the block number and why the series stopped (`model.design.StopReason`: the target half-width was
reached, the budget was used up, or no distance was safe).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

from model.design import StopReason
from rig.inputs.protocol import AdaptiveBlock
from rig.records import TrialResult

if TYPE_CHECKING:
    from rig.study.worker import JointResult

# Scores a set of trials: one JointResult per joint that has joint-estimation trials among them.
ScoreTrials = Callable[[Sequence[TrialResult]], "tuple[JointResult, ...]"]


def score_series(
    results: Sequence[TrialResult],
    adaptive: Sequence[AdaptiveBlock],
    stops: Mapping[int, StopReason | None],
    score: ScoreTrials,
) -> tuple[JointResult, ...]:
    """Every series' case: the fixed trials' per joint, then each adaptive block's, ordered by joint.

    `stops` maps an adaptive block's number to why it stopped (None: it had not, e.g. an aborted run).
    Without adaptive blocks this is `score(results)` itself.
    """
    owner = {trial_id: block for block in adaptive for trial_id in block.trial_ids}
    fixed = [r for r in results if r.trial_id not in owner]
    cases = list(score(fixed))
    for block in adaptive:
        own = [r for r in results if owner.get(r.trial_id) is block]
        stop = stops.get(block.block)
        cases += [replace(case, block=block.block, stop_reason=stop) for case in score(own)]
    return tuple(sorted(cases, key=lambda c: (c.joint, -1 if c.block is None else c.block)))
