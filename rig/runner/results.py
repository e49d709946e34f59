"""A trial's measurements as the steps gather them, the `TrialResult` made from them, and run statistics.

A trial's outcome (`TrialOutcome`): a detected slip of the joint under test is `slip`, `creep` or
`stick_slip` (`slip_outcome`); a slip of another joint is `other_joint`; no slip up to the force
limit or the end of the winch's travel is `no_slip`; a step that timed out is `aborted`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import assert_never

from model.payload_errors import PayloadErrorStats, payload_error_stats, signed_percentage_error
from model.slip_detector import SlipEvent, SlipEventKind
from rig.hw.seams import ConfigurationReading
from rig.inputs.protocol import TrialPlan
from rig.records import SLIP_LIKE, TrialKind, TrialOutcome, TrialResult


@dataclass
class TrialMeasurements:
    """What the steps of one trial found out, filled in as they run."""

    joint_angles_rad: tuple[float, ...] | None  # commanded, replaced by the measured ones
    predicted_force_n: float | None = None
    lever_arms_m: tuple[float, ...] | None = None
    outcome: TrialOutcome = TrialOutcome.NO_SLIP
    event: SlipEvent | None = None
    peak_observed_n: float | None = None  # highest tension during the ramp
    slipped_joint: int | None = None
    train_drops: int = 0  # further drops in the hold after the event
    reason: str | None = None  # why the trial was aborted
    measured: ConfigurationReading | None = None  # the configuration measured after bending
    line_released: bool = False  # released after the slip, before anything slow (`rig.runner.unloading`)


def slip_outcome(
    trial: TrialPlan, event: SlipEvent, train_drops: int, slipped_joint: int | None
) -> TrialOutcome:
    """The outcome of a trial whose ramp ended in a confirmed slip event.

    `other_joint` when a joint-estimation trial's configuration source names another joint as the
    one that moved (None: unknown, taken as the joint under test); else `stick_slip` when further
    drops followed in the hold, `creep` for an event of kind creep, `slip` for a sudden drop.
    """
    if (
        trial.kind == TrialKind.JOINT_ESTIMATION
        and slipped_joint is not None
        and trial.joint is not None
        and slipped_joint != trial.joint
    ):
        return TrialOutcome.OTHER_JOINT
    if train_drops > 0:
        return TrialOutcome.STICK_SLIP
    match event.kind:
        case SlipEventKind.CREEP:
            return TrialOutcome.CREEP
        case SlipEventKind.DROP:
            return TrialOutcome.SLIP
        case kind:
            assert_never(kind)


def trial_result(
    trial: TrialPlan,
    found: TrialMeasurements,
    *,
    start_time_ns: int,
    end_time_ns: int,
    tare_n: float,
    g: float,
) -> TrialResult:
    """The record of a finished trial: the slip load is the detector's peak, else the highest tension."""
    event = found.event
    peak = event.peak_force_n if event is not None else found.peak_observed_n
    predicted_force = found.predicted_force_n
    predicted_mass = predicted_force / g if predicted_force is not None else None
    slip_mass = peak / g if peak is not None else None
    percentage_error = None
    if (
        found.outcome in SLIP_LIKE
        and predicted_mass is not None
        and slip_mass is not None
        and trial.kind == TrialKind.LINK_VALIDATION
    ):
        percentage_error = signed_percentage_error(predicted_mass, slip_mass)
    return TrialResult(
        trial_id=trial.trial_id,
        kind=TrialKind(trial.kind),
        repeat=trial.repeat,
        joint=trial.joint,
        distance_m=trial.distance_m,
        configuration_index=trial.configuration_index,
        joint_angles_rad=found.joint_angles_rad,
        start_time_ns=start_time_ns,
        end_time_ns=end_time_ns,
        outcome=found.outcome,
        peak_force_n=peak,
        slip_mass_kg=slip_mass,
        predicted_force_n=predicted_force,
        predicted_mass_kg=predicted_mass,
        percentage_error=percentage_error,
        slipped_joint=found.slipped_joint,
        lever_arms_m=found.lever_arms_m,
        tare_n=tare_n,
        reason=found.reason,
    )


def percentage_error_stats(results: Sequence[TrialResult]) -> PayloadErrorStats | None:
    """Table IV statistics over the link-validation slips of a run, or None if there are none."""
    pairs = [
        (r.predicted_mass_kg, r.slip_mass_kg)
        for r in results
        if r.kind == TrialKind.LINK_VALIDATION and r.slipped and r.predicted_mass_kg and r.slip_mass_kg
    ]
    if not pairs:
        return None
    predicted, measured = zip(*pairs, strict=True)
    return payload_error_stats(predicted, measured)


def nothing_measured(results: Sequence[TrialResult], max_force_n: float) -> str | None:
    """Why a run whose trials are all done measured no slip (None when one trial slipped, or none ran).

    A run that measured nothing must not end as if it had (exit 1, `rig run`): the text names what
    the trials ended in and the most likely cause.
    """
    if not results or any(r.slipped for r in results):
        return None
    counts = {o: sum(r.outcome == o for r in results) for o in TrialOutcome}
    tally = ", ".join(f"{n} {o}" for o, n in counts.items() if n)
    head = f"no trial gave a usable slip ({tally} of {len(results)})"
    if counts[TrialOutcome.ABORTED] == len(results):
        first = next((r.reason for r in results if r.reason), "unknown")
        return (
            f"{head}: every trial was aborted, the first by: {first}. If the ramps timed out, the tension "
            "did not rise as planned: check that the line is on the drum and tied to the link, "
            "loadcell.rate_hz and line_stiffness_n_per_m against `rig check --move`"
        )
    if counts[TrialOutcome.NO_SLIP] == len(results):
        peak = max((r.peak_force_n or 0.0) for r in results)
        return (
            f"{head}: no joint slipped below ramp.max_force_n ({max_force_n:g} N; the highest tension "
            f"{peak:.2f} N): the joints hold more than the protocol allows, or the winch's travel ended "
            "first; raise ramp.max_force_n within the ceilings, or hook the line further out"
        )
    if counts[TrialOutcome.OTHER_JOINT] == len(results):
        return (
            f"{head}: every slip was of another joint than the one under test: that joint holds more "
            "than the ones beside it at these distances (docs/model.md), or the configuration source "
            "names joints wrongly"
        )
    return f"{head}: see each trial's outcome and reason in the summary"
