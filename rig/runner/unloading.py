"""Unloading the line with the interlocks live: the unload step's motion, and the release before a wait.

Nothing waits for a person or a slow measurement while the line is loaded (docs/design.md §6):
after a slip the line is released before the configuration is measured again (an operator asked
which joint moved, a camera capture), and any step that waits for the operator first releases a
line the winch still holds away from its zero. A release after a slip is timed from the
detection to the cell reading the line slack, against `limits.max_loaded_after_slip_s`.
The release after a failure, which must not depend on the load cell or on replies, is
`rig.safety.release`.
"""

from __future__ import annotations

from rig.inputs.protocol import TrialPlan
from rig.records import LogLevel, ServoCommandName, TrialPhase
from rig.runner.step_context import StepContext
from rig.safety.safe_state import POSITION_TOLERANCE_RAD, move_timeout_s
from rig.vocabulary import StepKind

# How the log names the time from a slip's detection to the line slack (studies/loaded_after_slip.py).
LOADED_AFTER_SLIP = "line released after the slip in"
# The line counts as released once the winch is home and the cell reads less than this above its tare.
RELEASED_TENSION_N = 0.5


def winch_at_zero(ctx: StepContext) -> bool:
    """The winch is at its zero-tension angle (as last read); True when there is no zero yet."""
    zero = ctx.winch_zero_rad
    if zero is None:
        return True
    return abs(ctx.loop.states[ctx.session.winch_id].position_rad - zero) < POSITION_TOLERANCE_RAD


def unload_line(ctx: StepContext, trial: TrialPlan) -> None:
    """Back the winch off to its zero-tension angle and wait until the cell reads the line slack.

    StepTimeoutError if the winch is not home with the line slack within the move's timeout.
    """
    ctx.recorder.phase(TrialPhase.UNLOADING, trial.trial_id, StepKind.UNLOAD)
    loop = ctx.loop
    winch = ctx.session.winch_id
    zero = ctx.winch_zero_rad
    if zero is None:
        return
    speed = ctx.protocol.ramp.unload_speed_rad_s
    ctx.session.servos.set_profile(winch, velocity_rad_s=speed)
    ctx.session.servos.write_goal_positions({winch: zero})
    ctx.recorder.command(winch, ServoCommandName.GOAL_POSITION, zero, "rad")

    def done() -> bool:
        home = abs(loop.states[winch].position_rad - zero) < POSITION_TOLERANCE_RAD
        return home and loop.force_n < RELEASED_TENSION_N + abs(loop.tare_n)

    travel = loop.states[winch].position_rad - zero
    loop.wait_until(done, move_timeout_s(travel, speed, ctx.protocol.step_timeout_margin_s), StepKind.UNLOAD)


def release_after_slip(ctx: StepContext, trial: TrialPlan, detection_time_ns: int) -> None:
    """Unload right after a slip's hold, before anything slow; warn if it took longer than the bound.

    The time loaded is from the slip's detection to the cell reading the line slack at the
    winch's zero (the hold after the slip and the unload's travel).
    """
    unload_line(ctx, trial)
    loaded_s = (ctx.loop.clock.time_ns() - detection_time_ns) / 1e9
    bound_s = ctx.config.limits.max_loaded_after_slip_s
    if loaded_s > bound_s:
        ctx.recorder.note(
            LogLevel.WARNING,
            f"trial {trial.trial_id}: {LOADED_AFTER_SLIP} {loaded_s:.3f} s, beyond "
            f"limits.max_loaded_after_slip_s ({bound_s:g} s): shorten ramp.hold_after_slip_s or raise "
            "ramp.unload_speed_rad_s",
        )
    else:
        ctx.recorder.note(LogLevel.INFO, f"trial {trial.trial_id}: {LOADED_AFTER_SLIP} {loaded_s:.3f} s")


def release_before_waiting(ctx: StepContext, trial: TrialPlan) -> None:
    """Before a step waits for the operator: release the line if the winch is not at its zero."""
    if winch_at_zero(ctx):
        return
    ctx.recorder.note(
        LogLevel.WARNING,
        f"trial {trial.trial_id}: releasing the line before waiting for the operator",
    )
    unload_line(ctx, trial)
