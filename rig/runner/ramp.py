"""The ramp_until_slip step: drive the winch (fast, then slow) and feed the detector until a slip.

Two parts with their own state: `WinchDrive` moves the winch (its speed, a goal kept a short way
ahead of it, the end of its travel) and `DetectorFeed` hands every sample stamped since the ramp
began to the slip detector, confirms what fires, and counts the further drops in the hold after
the slip. `ramp_until_slip` ticks the control loop and passes each tick to both.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import assert_never

from model.slip_detector import (
    DetectorParams,
    DetectorState,
    SlipEvent,
    detector_init,
    detector_run,
    further_drops,
)
from model.slipped_joint import moved_joint, noise_threshold_rad
from rig.errors import InterlockTripped, StepTimeoutError
from rig.hw.configuration.factory import sees_slips
from rig.hw.dxl.units import RAD_PER_PULSE, RAD_S_PER_VELOCITY_UNIT
from rig.hw.seams import LoadCellSample
from rig.inputs.protocol import TrialPlan
from rig.log.format import schemas
from rig.records import LogLevel, ServoCommandName, SlipMessage, TrialOutcome, TrialPhase
from rig.runner.control_loop import ControlLoop
from rig.runner.direction_check import ReelDirectionCheck
from rig.runner.measuring import measure_configuration
from rig.runner.ramp_speed import BAND_Z, SPEED_STEP, RampSpeeds
from rig.runner.results import TrialMeasurements, slip_outcome
from rig.runner.step_context import StepContext
from rig.runner.unloading import release_after_slip
from rig.safety.safe_state import POSITION_TOLERANCE_RAD
from rig.vocabulary import StepKind, TrialKind

# How far ahead of the winch its ramp goal is kept, in seconds of motion at the ramp's speed.
RAMP_GOAL_LEAD_S = 0.5
# A tension drop while the winch turns back faster than this is the winch backing off, not a slip.
_BACKING_OFF_RAD_S = -0.05
# A measured load-cell rate this far (relative) from the configured one is warned about, once the
# ramp has fed samples over at least RATE_MIN_SPAN_S.
RATE_TOLERANCE = 0.2
RATE_MIN_SPAN_S = 1.0
# How much older than its read time a servo's position may be (the status packet's transit; a
# bus transaction at 1 Mbps takes about a millisecond). Not verified on hardware.
STATE_AGE_MARGIN_S = 0.003


class WinchDrive:
    """Reels the winch in towards `limit_rad`, the goal never more than a short lead ahead of it."""

    def __init__(self, ctx: StepContext, limit_rad: float) -> None:
        self.reel = ctx.config.reel_direction  # +1: reeling in increases the winch's position
        self.loop = ctx.loop
        self.recorder = ctx.recorder
        self.servos = ctx.session.servos
        self.winch = ctx.session.winch_id
        self.limit_rad = limit_rad
        self.period_s = ctx.protocol.control_period_s
        self.speed_rad_s = 0.0
        self.goal_rad: float | None = None
        self.stepped = False  # the goal is stepped on (a speed below one velocity unit)
        self.anchor_rad = 0.0  # where the winch was, and when, at the last speed change
        self.anchor_ns = 0

    def set_speed(self, speed_rad_s: float) -> None:
        """Change the winch's profile speed and set a new goal for it.

        Below one Profile Velocity unit the servo cannot be told the speed (0 would mean no limit):
        the profile is set to one unit and the goal is stepped on at `speed_rad_s`, count by count.
        """
        # The position was read a moment ago: the winch has gone on at the old speed since, and a
        # stepped goal behind it would turn it back (a fall of tension, a false peak). A goal far
        # ahead of it is as bad the other way: the winch catches up at one velocity unit, faster
        # than the stepped speed (at 10/s, 13 counts after the fast phase when the lead was a whole
        # control period). So the lead is the old speed over the read's age and a margin.
        # From one stepped speed to another the ramp goes on from where the old one had taken the
        # goal (re-anchoring at the winch, which lags its goal, turned it back and lost the counts
        # made so far: a stall, which at 10/s the detector read as a drop).
        state = self.loop.states[self.winch]
        age_s = max(0.0, (self.loop.clock.time_ns() - state.time_ns) * 1e-9) + STATE_AGE_MARGIN_S
        anchor = self.reel * state.position_rad + self.speed_rad_s * min(self.period_s, age_s)
        if self.stepped and self.goal_rad is not None:
            anchor = max(anchor, min(self.reel * self.limit_rad, self._stepped_target()))
        self.speed_rad_s = speed_rad_s
        self.stepped = speed_rad_s < RAD_S_PER_VELOCITY_UNIT
        profile = RAD_S_PER_VELOCITY_UNIT if self.stepped else speed_rad_s
        self.servos.set_profile(self.winch, velocity_rad_s=profile)
        self.goal_rad = None
        self.anchor_rad = self.reel * anchor
        self.anchor_ns = self.loop.clock.monotonic_ns()
        self.advance()

    def _stepped_target(self) -> float:
        """Where the stepped speed has taken the goal since the anchor (reel-in coordinates)."""
        elapsed_s = (self.loop.clock.monotonic_ns() - self.anchor_ns) * 1e-9
        return self.reel * self.anchor_rad + self.speed_rad_s * elapsed_s

    def advance(self, sampled: bool = True) -> None:
        """Keep the winch's goal a short way ahead of it, never the far end of its travel.

        The goal leads the winch by `RAMP_GOAL_LEAD_S` of motion and is moved on once the winch is
        halfway there. If the host stops talking (crash, lost link), the winch stops within that
        lead instead of reeling on to `limit_rad`. Stepped (below one velocity unit): the goal is
        where the speed has taken it since `set_speed`, written when it has moved a count and only
        on a tick that brought a load-cell sample (`sampled`): each step then comes right after a
        sample and the tension's plateau before it is sampled (rig/runner/ramp_speed.py).
        """
        reel = self.reel  # in reel-in coordinates (the sign times the position) the goal only grows
        if self.stepped:
            if not sampled and self.goal_rad is not None:
                return
            target = min(reel * self.limit_rad, self._stepped_target())
            if self.goal_rad is not None:
                # Whole counts from the last goal, so each step is the counts the speed has made.
                counts = math.floor((target - reel * self.goal_rad) / RAD_PER_PULSE)
                if counts < 1:
                    return
                target = reel * self.goal_rad + counts * RAD_PER_PULSE
            self.goal_rad = reel * target
            self.servos.write_goal_positions({self.winch: self.goal_rad})
            self.recorder.command(self.winch, ServoCommandName.GOAL_POSITION, self.goal_rad, "rad")
            return
        position = reel * self.loop.states[self.winch].position_rad
        lead = self.speed_rad_s * RAMP_GOAL_LEAD_S
        goal = self.goal_rad
        if goal is not None and (reel * goal >= reel * self.limit_rad or reel * goal - position > lead / 2):
            return
        self.goal_rad = reel * min(reel * self.limit_rad, position + lead)
        self.servos.write_goal_positions({self.winch: self.goal_rad})
        self.recorder.command(self.winch, ServoCommandName.GOAL_POSITION, self.goal_rad, "rad")

    def travel_exhausted(self) -> bool:
        """The winch has reached the end of its allowed travel."""
        reel = self.reel
        return (
            reel * self.loop.states[self.winch].position_rad >= reel * self.limit_rad - POSITION_TOLERANCE_RAD
        )

    def hold(self) -> None:
        """Stop reeling: the goal is where the winch is now."""
        hold = self.loop.states[self.winch].position_rad
        self.servos.write_goal_positions({self.winch: hold})
        self.recorder.command(self.winch, ServoCommandName.GOAL_POSITION, hold, "rad")


class DetectorFeed:
    """The slip detector over the samples stamped at or after `start_ns`, until a confirmed slip.

    `start_ns` is also the log time of the ramp's phase change, so `rig replay` can feed the
    detector the very same samples. The samples stamped at that very instant came with the last
    tick (`already_read`): they are fed first.
    """

    def __init__(
        self,
        params: DetectorParams,
        start_ns: int,
        already_read: list[LoadCellSample],
        confirm: Callable[[SlipEvent], bool],
    ) -> None:
        self.params = params
        self.start_ns = start_ns
        self._pending = [s for s in already_read if s.time_ns >= start_ns]
        self.confirm = confirm
        self.state: DetectorState = detector_init(params)
        self.peak_n = 0.0
        self.event: SlipEvent | None = None
        self.after_event: list[LoadCellSample] = []  # samples of the detecting tick after the event
        self.first_ns: int | None = None  # the first and last sample fed, and how many
        self.last_ns = 0
        self.fed = 0

    def measured_rate_hz(self) -> float | None:
        """The rate the samples fed so far came at (None before `RATE_MIN_SPAN_S` of them)."""
        if self.first_ns is None or self.fed < 3 or self.last_ns - self.first_ns < RATE_MIN_SPAN_S * 1e9:
            return None
        return (self.fed - 1) / ((self.last_ns - self.first_ns) * 1e-9)

    def feed(self, tick_samples: list[LoadCellSample]) -> SlipEvent | None:
        """Step the detector over one tick's samples; the confirmed slip, if one fired."""
        params = self.params
        samples = self._pending + tick_samples
        self._pending = []
        fed = [i for i, s in enumerate(samples) if s.time_ns >= self.start_ns]
        times = [samples[i].time_ns for i in fed]
        forces = [samples[i].force_n for i in fed]
        if times:
            if self.first_ns is None:
                self.first_ns = times[0]
            self.last_ns = times[-1]
            self.fed += len(times)
        j = 0
        while j < len(fed):
            # detector_run: detector_step over the samples until one fires (with a fast path).
            self.state, k, fired = detector_run(params, self.state, times, forces, j)
            self.peak_n = max(self.peak_n, *forces[j : k + 1])
            if fired is None:
                break
            if self.confirm(fired):
                self.event = fired
                self.after_event = samples[fed[k] + 1 :]
                break
            self.state = detector_init(params)  # not a slip: start over, so a real one is seen
            j = k + 1
        return self.event

    def drops_in_hold(self, loop: ControlLoop, hold_s: float) -> int:
        """Tick for `hold_s` after the slip; the further drops the latched detector counts in it.

        The detector is stepped over the samples up to `hold_s` after the detection (a window of
        sample times, so that replay picks the same samples).
        """
        event = self.event
        assert event is not None
        end_ns = event.detection_time_ns + round(hold_s * 1e9)
        samples = list(self.after_event)
        stop = loop.clock.monotonic_ns() + round(hold_s * 1e9)
        while loop.clock.monotonic_ns() < stop:
            loop.tick()
            samples += loop.tick_samples
        window = [s for s in samples if s.time_ns <= end_ns]
        times, forces = [s.time_ns for s in window], [s.force_n for s in window]
        _, drops = further_drops(self.params, self.state, times, forces)
        return drops


def predicted_force_n(ctx: StepContext, trial: TrialPlan, found: TrialMeasurements) -> float | None:
    """The slip force the estimates so far predict for this trial (recorded in `found`)."""
    match trial.kind:
        case TrialKind.JOINT_ESTIMATION:
            assert trial.distance_m is not None
            found.predicted_force_n = ctx.estimator.predict_joint_estimation_force_n(trial.distance_m)
            found.lever_arms_m = None
            return found.predicted_force_n
        case TrialKind.LINK_VALIDATION:
            prediction = ctx.estimator.predict_link(found.joint_angles_rad or ())
            if prediction is None:
                raise InterlockTripped("link validation needs joint estimates, and none are available")
            found.predicted_force_n = prediction.slip_force_n
            found.lever_arms_m = prediction.lever_arms_m
            return prediction.slip_force_n
        case kind:
            assert_never(kind)


def ramp_until_slip(ctx: StepContext, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Load the line, fast to a share of the predicted slip force and slow after, until a slip.

    The slow speed is capped so that one sample period's rise is a small share of the tension
    (`rig.runner.ramp_speed`): at low load-cell rates the ramp slows as the tension climbs towards
    the expected slip load, and reels fast up to the low edge of it.
    Until a ramp of the run has seen the tension rise, each verifies the reel direction
    (`rig.runner.direction_check`): a winch that turns `limits.direction_check_rev` without the
    tension rising stops the run.
    After a slip the winch holds `hold_after_slip_s` to count the further drops and the line is then
    released (`rig.runner.unloading`) before the configuration is measured again. At the ramp's force
    limit or the winch's travel the trial is `no_slip`, the winch holding where it is.
    """
    ramp = ctx.protocol.ramp
    loop, recorder = ctx.loop, ctx.recorder
    speeds = RampSpeeds(
        fast_rad_s=ramp.fast_speed_rad_s,
        slow_rad_s=ramp.slow_speed_rad_s,
        rate_hz=ctx.loadcell_rate_hz,
        n_per_rad=ctx.line_stiffness_n_per_m * ctx.config.spool_radius_m,
    )
    predicted = predicted_force_n(ctx, trial, found)
    arm_n = ctx.detector_params.arm_threshold_n
    # Where the sampling limit binds (low rates) the fast phase runs up to the low edge of the
    # expected slip load (`plan.capped_n`; for joint estimation, where the estimator gives one).
    # Between samples (up to 0.1 s apart at 10/s, 5 N at full speed) the tension is read ahead
    # from the winch's travel since the last sample.
    low_n = None
    if trial.kind == TrialKind.JOINT_ESTIMATION and trial.distance_m is not None:
        low_n = ctx.estimator.joint_estimation_force_low_n(trial.distance_m, BAND_Z)
    plan = speeds.plan(arm_n, predicted, low_n, ramp.fast_until_fraction, ctx.protocol.control_period_s)
    switch_n, read_ahead = plan.switch_n, plan.read_ahead

    # Nothing to go on, or below the expected range: the count floor. Latched off once the tension
    # has reached the range (noise about its edge would flip it).
    counted = True

    def slow_speed(force_n: float) -> float:
        # The limit holds from the end of the fast phase, the approach to `capped_n` included: a
        # slip below the expected range's low edge is read as finely as one inside it.
        nonlocal counted
        if plan.expected and force_n >= plan.capped_n:
            counted = False
        return speeds.slow_at(force_n, arm_n, counted=counted)

    zero = ctx.winch_zero_rad
    assert zero is not None
    reel = ctx.config.reel_direction
    drive = WinchDrive(ctx, zero + reel * ctx.config.limits.max_winch_travel_rev * 2 * math.pi)
    # Timeout from the motion: the slow ramp from the arm threshold to the protocol's maximum force,
    # with the nominal line stiffness, three times over, plus the margin.
    slow_s = max(
        ramp.max_force_n / (speeds.n_per_rad * ramp.slow_speed_rad_s),
        speeds.slow_ramp_s(arm_n, ramp.max_force_n),
    )
    timeout_s = 3.0 * slow_s + ctx.protocol.step_timeout_margin_s
    deadline = loop.clock.monotonic_ns() + round(timeout_s * 1e9)

    fast = loop.force_n < switch_n
    start_ns = loop.clock.time_ns()
    feed = DetectorFeed(
        ctx.detector_params, start_ns, loop.tick_samples, lambda e: _confirmed_by_winch(ctx, e)
    )
    recorder.phase(
        TrialPhase.RAMP_FAST if fast else TrialPhase.RAMP_SLOW,
        trial.trial_id,
        StepKind.RAMP_UNTIL_SLIP,
        start_ns,
    )
    drive.set_speed(ramp.fast_speed_rad_s if fast else slow_speed(loop.force_n))
    view = ctx.link_view
    view.ramp_started(trial, found, loop.force_n, start_ns)
    sampled_at_rad: float | None = None  # the winch's position (reel-in sense) at the newest sample
    direction = ReelDirectionCheck(
        ctx.config,
        trial.trial_id,
        reel * loop.states[ctx.session.winch_id].position_rad,
        loop.force_n,
        verified=ctx.reel_direction_verified,
    )
    while feed.event is None:
        loop.tick()
        event = feed.feed(loop.tick_samples)
        found.peak_observed_n = feed.peak_n
        view.ramp_tick(trial, found, loop.force_n, loop.clock.time_ns())
        if event is not None:
            break
        position_rad = reel * loop.states[ctx.session.winch_id].position_rad
        ctx.reel_direction_verified = direction.update(position_rad, loop.force_n)
        if loop.tick_samples or sampled_at_rad is None:
            sampled_at_rad = position_rad
        force_n = loop.force_n
        if read_ahead and force_n >= arm_n:  # the line is taut: its take-up shows as tension
            force_n += speeds.n_per_rad * max(0.0, position_rad - sampled_at_rad)
        if fast and force_n >= switch_n:
            fast = False
            drive.set_speed(slow_speed(loop.force_n))
            recorder.phase(TrialPhase.RAMP_SLOW, trial.trial_id, StepKind.RAMP_UNTIL_SLIP)
        elif not fast and _speed_moved(drive.speed_rad_s, slow_speed(loop.force_n)):
            drive.set_speed(slow_speed(loop.force_n))
        else:
            drive.advance(sampled=bool(loop.tick_samples))
        if loop.force_n >= ramp.max_force_n:
            found.outcome = TrialOutcome.NO_SLIP
            recorder.note(LogLevel.WARNING, f"trial {trial.trial_id}: no slip up to {ramp.max_force_n:.1f} N")
            break
        if drive.travel_exhausted():
            found.outcome = TrialOutcome.NO_SLIP
            recorder.note(LogLevel.WARNING, f"trial {trial.trial_id}: winch travel exhausted without a slip")
            break
        if loop.clock.monotonic_ns() > deadline:
            raise StepTimeoutError(
                f"trial {trial.trial_id}: ramp_until_slip exceeded its timeout of {timeout_s:.1f} s"
            )
    drive.hold()  # and keep logging the post-slip tension briefly
    found.peak_observed_n = feed.peak_n
    _check_rate(ctx, feed)
    if feed.event is not None:
        _record_slip(ctx, trial, found, feed)


def _speed_moved(speed_rad_s: float, target_rad_s: float) -> bool:
    """The slow phase's speed should be rewritten: its target has moved by more than a step."""
    return target_rad_s > speed_rad_s * SPEED_STEP or target_rad_s * SPEED_STEP < speed_rad_s


def _check_rate(ctx: StepContext, feed: DetectorFeed) -> None:
    """Warn once per run when the ramp's samples came at a rate far from the configured one."""
    measured = feed.measured_rate_hz()
    if measured is None or ctx.rate_mismatch_noted:
        return
    if abs(measured / ctx.loadcell_rate_hz - 1.0) > RATE_TOLERANCE:
        ctx.rate_mismatch_noted = True
        ctx.recorder.note(
            LogLevel.WARNING,
            f"load cell measured at {measured:.1f} samples/s, configured {ctx.loadcell_rate_hz:g}/s "
            f"(more than {RATE_TOLERANCE:.0%} off): the detector's and the ramp's rate-derived "
            "defaults assume the configured rate; set loadcell.rate_hz",
        )


def _record_slip(ctx: StepContext, trial: TrialPlan, found: TrialMeasurements, feed: DetectorFeed) -> None:
    """After a confirmed slip: hold, count further drops, release the line, ask which joint moved, log.

    The line is released before the configuration is measured again: that may wait for a person
    (which joint moved?) or a camera, and nobody waits beside a loaded line.
    """
    event = feed.event
    assert event is not None
    found.event = event
    found.train_drops = feed.drops_in_hold(ctx.loop, ctx.protocol.ramp.hold_after_slip_s)
    release_after_slip(ctx, trial, event.detection_time_ns)
    found.line_released = True
    found.slipped_joint = _slipped_joint(ctx, trial, found)
    found.outcome = slip_outcome(trial, event, found.train_drops, found.slipped_joint)
    message = SlipMessage(
        trial.trial_id, event, feed.params.to_mapping(), found.slipped_joint, found.train_drops
    )
    ctx.recorder.write(schemas.SLIP, message.to_payload(), event.detection_time_ns)
    ctx.link_view.show(trial, found, event.peak_force_n, event.detection_time_ns)
    if found.outcome != TrialOutcome.SLIP:
        ctx.recorder.note(LogLevel.INFO, f"trial {trial.trial_id}: {found.outcome} ({_why(found)})")


def _slipped_joint(ctx: StepContext, trial: TrialPlan, found: TrialMeasurements) -> int | None:
    """The joint that moved, where the source sees it: as it says, or from the configuration before/after."""
    kind = ctx.session.configuration_kind
    if ctx.session.configuration is None or (kind is not None and not sees_slips(kind)):
        return None
    after = measure_configuration(ctx, trial, after_slip=True)
    if after.slipped_joint is not None:
        return after.slipped_joint
    before = found.measured
    if before is None or before.transforms.shape != after.transforms.shape:
        return None
    sd = None if after.uncertainty_rad is None else max(after.uncertainty_rad, default=None)
    return moved_joint(before.transforms, after.transforms, noise_threshold_rad(sd))


def _confirmed_by_winch(ctx: StepContext, event: SlipEvent) -> bool:
    """A tension drop is a slip only if the winch was not backing off (it reels in or holds)."""
    winch = ctx.loop.states.get(ctx.session.winch_id)
    if winch is None or winch.hardware_error:
        return False
    confirmed = ctx.config.reel_direction * winch.velocity_rad_s > _BACKING_OFF_RAD_S
    if not confirmed:
        ctx.recorder.note(
            LogLevel.WARNING, f"drop at {event.peak_force_n:.2f} N ignored: winch was backing off"
        )
    return confirmed


def _why(found: TrialMeasurements) -> str:
    """A few words on why a slip got the outcome it has (for the log)."""
    event = found.event
    if found.outcome == TrialOutcome.OTHER_JOINT:
        return f"joint {found.slipped_joint} moved"
    if found.outcome == TrialOutcome.STICK_SLIP:
        return f"{found.train_drops} further drop(s) after the first"
    return (
        f"{event.trigger} after {(event.detection_time_ns - event.onset_time_ns) / 1e9:.3f} s"
        if event
        else ""
    )
