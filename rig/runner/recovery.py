"""After a device fault in a trial: may it clear, and does the rig recover once the line is released.

A device fault (a servo or load cell not answering, stale data, a latched hardware error) stops
the attempt in a trial-level safe state: the line is released (`rig.safety.release`; a faulted
winch is rebooted first). The rig has recovered when, within `limits.recovery_grace_s` (2 s by
default), every servo answers without a hardware error, the winch is home and the load cell
delivers fresh samples.
"""

from __future__ import annotations

from rig.errors import InterlockTripped, RigError, StepTimeoutError
from rig.hw.seams import ServoState
from rig.inputs.protocol import TrialPlan
from rig.records import LogLevel, TrialPhase
from rig.runner.step_context import StepContext
from rig.safety.safe_state import POSITION_TOLERANCE_RAD

# After a device fault in a trial: how many times the trial may be repeated.
MAX_TRIAL_RETRIES = 2


def is_device_fault(exc: RigError, states: dict[int, ServoState]) -> bool:
    """Whether `exc` is a device's fault that may clear (not a step timeout or a tension limit)."""
    if isinstance(exc, StepTimeoutError):
        return False
    if isinstance(exc, InterlockTripped):  # only the hardware-error interlock is a device's fault
        return any(state.hardware_error for state in states.values())
    return True


def recover(ctx: StepContext, trial: TrialPlan, exc: RigError) -> bool:
    """Release the line after a device fault and wait for a healthy rig; True if it recovered."""
    loop, note = ctx.loop, ctx.recorder.note
    clock, session = loop.clock, ctx.session
    note(LogLevel.WARNING, f"trial {trial.trial_id} stopped: {exc}; releasing the line")
    ctx.recorder.phase(TrialPhase.UNLOADING, trial.trial_id, "recover")
    zero = ctx.winch_zero_rad
    if zero is None:
        return False
    release = ctx.line_release()
    try:
        ctx.winch_zero_rad = zero = release.run(zero)
    except RigError as error:
        note(LogLevel.ERROR, f"trial {trial.trial_id}: release after the fault failed: {error}")
        return False
    finally:
        loop.adopt(release.reading())
    winch = session.winch_id
    grace_s = ctx.config.limits.recovery_grace_s
    deadline = clock.monotonic_ns() + round(grace_s * 1e9)
    while clock.monotonic_ns() < deadline:
        clock.sleep(ctx.protocol.control_period_s)
        try:
            loop.states = session.servos.read_states()
            samples = session.load_cell.poll()
        except RigError:
            continue
        loop.ingest(samples)
        loop.watchdog_trips()  # a trip found here is logged; the release resends its goal anyway
        home = abs(loop.states[winch].position_rad - zero) < POSITION_TOLERANCE_RAD
        if home and samples and not any(s.hardware_error for s in loop.states.values()):
            loop.restart_pacing()
            note(LogLevel.INFO, f"trial {trial.trial_id}: rig healthy again ({'; '.join(release.report)})")
            return True
    note(LogLevel.ERROR, f"trial {trial.trial_id}: the rig did not recover within {grace_s:g} s")
    return False
