"""The trial loop and its steps: runs a protocol's trials on a rig session, logging and refitting online.

One control tick reads the servo states (one sync read), drains the load cell (never blocking),
logs both, checks the interlocks, and hands the samples to the step in progress. Steps are small
methods (tare, bend, measure, prompt, ramp_until_slip, unload, reset, pause) driven by the
protocol's per-trial template. Whatever ends the run (success, interlock, fault, exception,
Ctrl-C), `run()` finishes in the safe state: line tension released, then torque off, inside a
block that a second Ctrl-C cannot interrupt, then the log is finished and the journal saved.
The stages of the safe state are `rig.runner.safe_state`; the trial's record is built by
`rig.runner.results`.
"""

from __future__ import annotations

import contextlib
import math
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from model.slip_detector import (
    DetectorState,
    SlipEvent,
    detector_init,
    detector_run,
    further_drops,
)
from rig.errors import (
    CommunicationError,
    ExitCode,
    HardwareFault,
    InterlockTripped,
    NotConnectedError,
    RigError,
    RigTimeoutError,
    StaleDataError,
    StepTimeoutError,
    ZeroNotVerified,
)
from rig.hw.seams import LoadCellSample, OperatingMode, ServoState
from rig.hw.session import RigSession
from rig.log import schemas
from rig.log.records import (
    LogLevel,
    LogMessage,
    ServoCommand,
    ServoCommandName,
    SlipMessage,
    TrialKind,
    TrialLinkStats,
    TrialOutcome,
    TrialResult,
    TrialState,
)
from rig.log.writer import LogWriteError, RunLogger
from rig.protocol import Protocol, StepSpec, TrialPlan
from rig.rig_config import RigConfig
from rig.runner.estimation import RunEstimator
from rig.runner.interlocks import CurrentAtLimit, ForceCeiling, ServoHealth
from rig.runner.journal import RunJournal
from rig.runner.link_counts import TrialLinkCounter
from rig.runner.phases import Phase, PhaseMachine
from rig.runner.progress import ProgressReporter
from rig.runner.results import TrialMeasurements, slip_outcome, trial_result
from rig.runner.safe_state import enter_safe_state, move_timeout_s
from rig.runner.safety import interrupts_held

_POSITION_TOLERANCE_RAD = 0.02
_RELEASED_TENSION_N = 0.5
_BENDER_SPEED_RAD_S = 2.0
# A line loaded at connect is paid out by this multiple of the travel that would release the reading
# at the nominal line stiffness (a real line is often softer than its nominal stiffness).
_ZERO_PAYOUT_FACTOR = 3.0
# The safe state waits this long beyond the winch's travel time: interlocks are off by then, and
# the load cell may be what failed, so arrival at the zero-tension angle is all it waits for.
_SAFE_STATE_MARGIN_S = 2.0
# After a device fault in a trial: how many times the trial may be repeated, and how long the rig
# has to answer healthily again (servos without a hardware error, fresh load-cell samples).
# How far ahead of the winch its ramp goal is kept, in seconds of motion at the ramp's speed.
RAMP_GOAL_LEAD_S = 0.5
MAX_TRIAL_RETRIES = 2
RECOVERY_GRACE_S = 2.0
_DEVICE_FAULTS = (
    StaleDataError,
    NotConnectedError,
    CommunicationError,
    RigTimeoutError,
    HardwareFault,
    InterlockTripped,
)
LINE_MAY_BE_LOADED = (
    "THE LINE MAY BE LOADED: switch off the servos' power before touching the link, then release the "
    "winch by hand"
)


@dataclass
class RunOutcome:
    """How a run invocation ended."""

    exit_code: ExitCode
    status: str  # journal status: completed, faulted, interrupted
    reason: str | None = None
    new_results: list[TrialResult] = field(default_factory=list)
    safe_state_verified: bool = True  # line released and torque off, both read back or confirmed


class TrialRunner:
    """Runs the remaining trials of a run on one session; see the module docstring."""

    def __init__(
        self,
        *,
        protocol: Protocol,
        config: RigConfig,
        session: RigSession,
        logger: RunLogger,
        journal: RunJournal,
        estimator: RunEstimator,
        progress: ProgressReporter,
        line_stiffness_n_per_m: float,
        log_ticks: bool = True,
    ) -> None:
        self.protocol = protocol
        self.config = config
        self.session = session
        self.clock = session.clock
        self.log = logger
        # False for a logger that keeps nothing (`rig study`'s): the per-tick rows are then not built.
        self._log_ticks = log_ticks
        self.journal = journal
        self.estimator = estimator
        self.progress = progress
        self.stiffness_n_per_m = line_stiffness_n_per_m
        self.detector_params = protocol.detector
        ceiling = config.limits.force_ceiling_n
        if protocol.force_ceiling_n is not None:
            ceiling = min(ceiling, protocol.force_ceiling_n)
        self.ceiling = ForceCeiling(ceiling)
        self.health = ServoHealth(dict(session.roles))
        self.current_limit = CurrentAtLimit(session.winch_id, config.limits.winch_current_limit_a, hold_s=1.0)
        self.phases = PhaseMachine()
        self.period_ns = round(protocol.control_period_s * 1e9)
        self._next_tick_ns = 0
        self.tare_n = 0.0
        self.force_n = 0.0  # latest tare-corrected tension
        self.states: dict[int, ServoState] = {}
        self.tick_samples: list[tuple[int, float]] = []  # (time_ns, tare-corrected force) this tick
        self.winch_zero_rad: float | None = None
        self.trial: TrialPlan | None = None
        self.connected = False
        self.release_report: list[str] = []  # what the safe state's release did and verified
        self.release_verified = False
        self._log_failed: LogWriteError | None = None
        self._best_effort = False

    # ------------------------------------------------------------------ run

    def run(self, trials: Iterable[TrialPlan]) -> RunOutcome:
        """Run `trials` in order and always end safe; returns the exit code and status.

        `trials` may be lazy (`rig.runner.planning.TrialSchedule`): the next trial is asked for only
        after the previous one is journalled.
        """
        outcome = RunOutcome(ExitCode.OK, "completed")
        try:
            self._connect()
            for trial in trials:
                outcome.new_results.append(self._run_trial_until_done(trial))
            self._phase(Phase.DONE, None)
        except KeyboardInterrupt:
            outcome = RunOutcome(
                ExitCode.INTERRUPTED, "interrupted", "interrupted by the operator", outcome.new_results
            )
            self._note(LogLevel.WARNING, "interrupted: releasing the line and turning torque off")
        except (InterlockTripped, StaleDataError, HardwareFault, RigTimeoutError) as exc:
            outcome = RunOutcome(
                ExitCode.FAULT, "faulted", f"{type(exc).__name__}: {exc}", outcome.new_results
            )
            self._note(LogLevel.ERROR, f"run stopped: {exc}")
        except RigError as exc:
            outcome = RunOutcome(
                ExitCode.FAULT, "faulted", f"{type(exc).__name__}: {exc}", outcome.new_results
            )
            self._note(LogLevel.ERROR, f"run stopped: {exc}")
        except Exception as exc:  # a bug must still end in the safe state, and be reported
            outcome = RunOutcome(ExitCode.FAULT, "faulted", f"internal error: {exc!r}", outcome.new_results)
            self._note(LogLevel.FATAL, "internal error: " + "".join(traceback.format_exception(exc)))
        finally:
            # Held, not re-raised after: the outcome is decided, and the caller must still save it.
            with interrupts_held() as late:
                safe_error = self._make_safe()
                if safe_error is not None:  # never hidden behind the reason the run stopped for
                    reason = safe_error if outcome.reason is None else f"{outcome.reason}; then {safe_error}"
                    exit_code = ExitCode.FAULT if outcome.exit_code == ExitCode.OK else outcome.exit_code
                    status = "faulted" if outcome.exit_code == ExitCode.OK else outcome.status
                    outcome = RunOutcome(exit_code, status, reason, outcome.new_results, False)
                if outcome.exit_code != ExitCode.OK and self.phases.phase not in (
                    Phase.ABORTED,
                    Phase.FAULTED,
                ):
                    self._phase(
                        Phase.ABORTED if outcome.exit_code == ExitCode.INTERRUPTED else Phase.FAULTED, None
                    )
                if late:
                    self._note(LogLevel.WARNING, "Ctrl-C/SIGTERM in the safe state: held until it ended")
        return outcome

    def announce(self, text: str, warning: bool = False) -> None:
        """A line for the log (`/rig/log`, INFO or WARNING) that the progress display shows too."""
        self._note(LogLevel.WARNING if warning else LogLevel.INFO, text)
        if not warning:  # a warning is shown by `_note` already
            self.progress.message(text)

    def _connect(self) -> None:
        self._phase(Phase.CONNECTING, None)
        servos = self.session.servos
        servos.connect()
        self.connected = True
        winch = self.session.winch_id
        servos.set_current_limit(winch, self.config.limits.winch_current_limit_a)
        servos.set_operating_mode(
            winch,
            OperatingMode.CURRENT_BASED_POSITION,
            goal_current_a=self.config.limits.winch_current_limit_a,
            profile_velocity_rad_s=self.protocol.ramp.fast_speed_rad_s,
        )
        self._command(winch, ServoCommandName.MODE, float(OperatingMode.CURRENT_BASED_POSITION), "")
        benders = [sid for sid, role in self.session.roles.items() if role == "bender"]
        for sid in benders:
            servos.set_operating_mode(
                sid, OperatingMode.EXTENDED_POSITION, profile_velocity_rad_s=_BENDER_SPEED_RAD_S
            )
            self._command(sid, ServoCommandName.MODE, float(OperatingMode.EXTENDED_POSITION), "")
        servos.set_torque([winch, *benders], True)
        for sid in (winch, *benders):
            self._command(sid, ServoCommandName.TORQUE, 1.0, "")
        self.session.load_cell.open()
        self._next_tick_ns = self.clock.monotonic_ns()
        self._tick(interlocks=False)
        while not self.tick_samples:  # a slow cell: the driver raises StaleDataError if none come
            self._tick(interlocks=False)
        self.winch_zero_rad = self.states[winch].position_rad
        self._verify_zero()
        self._check_interlocks()
        self._phase(Phase.IDLE, None)
        self._note(
            LogLevel.INFO,
            f"connected: servos {sorted(self.session.roles)}; winch zero {self.winch_zero_rad:.4f} rad",
        )

    def _verify_zero(self) -> None:
        """Refuse to take a loaded line as zero: the cell must read within the tolerance of its zero.

        Called at connect, after the first samples and before anything has moved (the winch holds
        where it stands). Beyond the tolerance the line may be loaded (a stop that could not release
        it) or the calibration's zero is off; either way the run stops (exit 1) with the reading. The
        winch's zero-tension angle is moved out by the travel that would release that reading
        (`_ZERO_PAYOUT_FACTOR` x, at the nominal stiffness, within the travel limit), so the safe
        state pays line out, never in, and then turns torque off.
        """
        samples = [f for _, f in self.tick_samples]
        reading_n = sum(samples) / len(samples)
        tolerance_n = self.config.limits.zero_tolerance_n
        if abs(reading_n) <= tolerance_n:
            return
        assert self.winch_zero_rad is not None
        k_angular = self.stiffness_n_per_m * self.config.spool_radius_m  # N per rad of winch
        payout_rad = min(
            _ZERO_PAYOUT_FACTOR * abs(reading_n) / k_angular,
            self.config.limits.max_winch_travel_rev * 2 * math.pi,
        )
        self.winch_zero_rad -= self.config.reel_direction * payout_rad  # pay out, never in
        raise ZeroNotVerified(
            f"the load cell reads {reading_n:+.2f} N at connect, beyond limits.zero_tolerance_n "
            f"({tolerance_n:g} N) of its calibrated zero, so the line may be loaded; nothing was reeled in, "
            f"the winch pays out {payout_rad:.2f} rad and its torque goes off: slacken the line by hand "
            "(or, if it is slack, recalibrate the load cell with `rig calibrate`) and start the run again"
        )

    # ------------------------------------------------------------------ ticks

    def _tick(self, *, interlocks: bool = True) -> None:
        """One control period: wait, read everything, log it, check the interlocks (unless told not to)."""
        if self._log_failed is not None:
            raise self._log_failed  # a run whose log cannot be written stops (a fault)
        self._next_tick_ns += self.period_ns
        now = self.clock.monotonic_ns()
        if self._next_tick_ns > now:
            self.clock.sleep((self._next_tick_ns - now) / 1e9)
        else:
            self._next_tick_ns = now  # late: do not try to catch up with a burst of ticks
        self.states = self.session.servos.read_states()
        samples = self.session.load_cell.poll()
        self._ingest(samples)
        if interlocks:
            self._check_interlocks()

    def _check_interlocks(self) -> None:
        """Raise InterlockTripped if this tick's samples or servo states trip an interlock."""
        now_ns = self.clock.monotonic_ns()
        reason = (
            self.ceiling.check(max((f for _, f in self.tick_samples), default=self.force_n))
            or self.health.check(self.states)
            or self.current_limit.check(self.states, now_ns)
        )
        if reason is not None:
            raise InterlockTripped(reason)

    def _ingest(self, samples: list[LoadCellSample]) -> None:
        tare = self.tare_n
        self.tick_samples = [(s.time_ns, s.force_n - tare) for s in samples]
        if samples:
            self.force_n = self.tick_samples[-1][1]
        if self._log_failed is not None or not self._log_ticks:
            return
        try:
            if samples:
                # Rows in schemas.ROW_FIELDS order (seq, raw, force_n, device_time_us): no dict per sample.
                self.log.log_many(
                    schemas.LOADCELL,
                    [
                        (t_ns, (s.seq, s.raw, force, s.device_time_us))
                        for s, (t_ns, force) in zip(samples, self.tick_samples, strict=True)
                    ],
                )
            roles = self.session.roles
            for state in self.states.values():
                self.log.log(
                    schemas.SERVO_STATE,
                    state.time_ns,
                    schemas.servo_state_payload(state, roles.get(state.servo_id, "")),
                )
        except LogWriteError as exc:
            self._logger_failed(exc)

    def _ticks_for(self, seconds: float) -> None:
        end = self.clock.monotonic_ns() + round(seconds * 1e9)
        while self.clock.monotonic_ns() < end:
            self._tick()

    def _wait_until(
        self, done: Callable[[], bool], timeout_s: float, what: str, step: Callable[[], None] | None = None
    ) -> None:
        """Call `step` (a control tick by default) until `done()`; RigTimeoutError after `timeout_s`."""
        step = step or self._tick
        deadline = self.clock.monotonic_ns() + round(timeout_s * 1e9)
        while not done():
            if self.clock.monotonic_ns() > deadline:
                raise StepTimeoutError(f"step {what} did not finish within its timeout of {timeout_s:.1f} s")
            step()

    # ------------------------------------------------------------------ trial

    def _run_trial_until_done(self, trial: TrialPlan) -> TrialResult:
        """Run a trial; after a device fault that clears, repeat it (at most `MAX_TRIAL_RETRIES` times).

        A device fault (a servo or load cell not answering, stale data, a latched hardware error)
        stops the attempt in a trial-level safe state: the line is released (a faulted winch is
        rebooted first). If within `RECOVERY_GRACE_S` every servo answers without a hardware error
        and the load cell delivers fresh samples, the trial starts again from its first step; the
        retry is logged and counted in the journal. Otherwise the fault ends the run (exit 1).
        """
        for retries in range(MAX_TRIAL_RETRIES + 1):
            try:
                return self._run_trial(trial)
            except (StaleDataError, NotConnectedError, CommunicationError, RigTimeoutError, HardwareFault,
                    InterlockTripped) as exc:  # fmt: skip
                if (
                    retries == MAX_TRIAL_RETRIES
                    or not self._device_fault(exc)
                    or not self._recover(trial, exc)
                ):
                    raise
            self.journal.record_retry(trial.trial_id)
            self._note(LogLevel.WARNING, f"trial {trial.trial_id}: the rig recovered; repeating the trial")
        raise AssertionError("unreachable")

    def _device_fault(self, exc: RigError) -> bool:
        """Whether `exc` is a device's fault that may clear (not a step timeout or a tension limit)."""
        if isinstance(exc, StepTimeoutError):
            return False
        if isinstance(exc, InterlockTripped):  # only the hardware-error interlock is a device's fault
            return any(state.hardware_error for state in self.states.values())
        return True

    def _recover(self, trial: TrialPlan, exc: RigError) -> bool:
        """Release the line after a device fault and wait for a healthy rig; True if it recovered."""
        self._note(LogLevel.WARNING, f"trial {trial.trial_id} stopped: {exc}; releasing the line")
        self._phase(Phase.UNLOADING, trial.trial_id, "recover")
        zero = self.winch_zero_rad
        if zero is None:
            return False
        self.release_report = []
        try:
            self.winch_zero_rad = zero = self._release_in_safe_state(zero)
        except RigError as error:
            self._note(LogLevel.ERROR, f"trial {trial.trial_id}: release after the fault failed: {error}")
            return False
        winch = self.session.winch_id
        deadline = self.clock.monotonic_ns() + round(RECOVERY_GRACE_S * 1e9)
        while self.clock.monotonic_ns() < deadline:
            self.clock.sleep(self.protocol.control_period_s)
            try:
                self.states = self.session.servos.read_states()
                samples = self.session.load_cell.poll()
            except RigError:
                continue
            self._ingest(samples)
            home = abs(self.states[winch].position_rad - zero) < _POSITION_TOLERANCE_RAD
            if home and samples and not any(s.hardware_error for s in self.states.values()):
                self._next_tick_ns = self.clock.monotonic_ns()
                self._note(
                    LogLevel.INFO,
                    f"trial {trial.trial_id}: rig healthy again ({'; '.join(self.release_report)})",
                )
                return True
        self._note(
            LogLevel.ERROR, f"trial {trial.trial_id}: the rig did not recover within {RECOVERY_GRACE_S:g} s"
        )
        return False

    def _run_trial(self, trial: TrialPlan) -> TrialResult:
        self.trial = trial
        self.session.begin_trial(trial)
        start_ns = self.clock.time_ns()
        self.progress.trial_started(trial.trial_id, self._describe(trial))
        found = TrialMeasurements(joint_angles_rad=trial.joint_angles_rad)
        links = TrialLinkCounter(self.session)
        try:
            for step in trial.steps:
                self._run_step(step, trial, found)
        except StepTimeoutError as exc:
            self._abort_trial(trial, found, exc)
        self._log_links(links.finish(trial.trial_id))
        result = trial_result(
            trial,
            found,
            start_time_ns=start_ns,
            end_time_ns=self.clock.time_ns(),
            tare_n=self.tare_n,
            g=self.config.article.g,
        )
        self.estimator.apply_result(result)
        estimate = self.estimator.estimate(trial.trial_id)
        log_time = self.clock.time_ns()
        self._log(schemas.TRIAL_RESULT, result.to_payload(), log_time)
        self._log(schemas.ESTIMATE, estimate.to_payload(), log_time)
        try:
            self.log.flush(wait=True)
        except LogWriteError as exc:
            self._logger_failed(exc)
        self.journal.record_trial(result)
        self.progress.trial_finished(result, estimate)
        return result

    def _abort_trial(self, trial: TrialPlan, found: TrialMeasurements, exc: StepTimeoutError) -> None:
        """A step timed out: release the line and, if the rig is healthy, record the trial as aborted.

        The run goes on with the next trial. If the line cannot be released or the rig does not
        answer healthily within `RECOVERY_GRACE_S`, the timeout ends the run (exit 1).
        """
        if not self._recover(trial, exc):
            raise exc
        found.outcome = TrialOutcome.ABORTED
        found.reason = str(exc)
        self._note(LogLevel.WARNING, f"trial {trial.trial_id}: aborted ({exc}); the run goes on")

    def _run_step(self, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
        kind = step.kind
        if kind == "prompt":
            self._phase(Phase.PROMPTING, trial.trial_id, "prompt")
            self.session.operator.confirm(trial.prompt_text(step.text or ""), trial, self._tick)
        elif kind == "tare":
            self._tare(step.duration_s, trial)
        elif kind == "bend":
            self._bend(trial)
        elif kind == "measure":
            self._measure(found)
        elif kind == "ramp_until_slip":
            self._ramp_until_slip(trial, found)
        elif kind == "unload":
            self._unload(trial)
        elif kind == "reset":
            self._reset(trial)
        elif kind == "pause":
            self._phase(Phase.PAUSING, trial.trial_id, "pause")
            self._ticks_for(step.duration_s)

    def _tare(self, settle_s: float, trial: TrialPlan) -> None:
        self._phase(Phase.TARING, trial.trial_id, "tare")
        self.tare_n = 0.0
        raw_forces: list[float] = []
        end = self.clock.monotonic_ns() + round(settle_s * 1e9)
        while self.clock.monotonic_ns() < end:
            self._tick()
            raw_forces += [f for _, f in self.tick_samples]
        if not raw_forces:
            raise StaleDataError(f"no load-cell samples during the {settle_s:.2f} s tare window")
        tare_n = sum(raw_forces) / len(raw_forces)
        tolerance_n = self.config.limits.zero_tolerance_n
        if abs(tare_n) > tolerance_n:  # an interlock, not a correction: the line is not slack at zero
            raise InterlockTripped(
                f"trial {trial.trial_id}: tare {tare_n:+.2f} N beyond limits.zero_tolerance_n "
                f"({tolerance_n:g} N): the line is not slack at the winch's zero, or the load cell's zero "
                "moved; slacken the line, check the cell, then resume the run"
            )
        self.tare_n = tare_n
        self._note(
            LogLevel.INFO, f"trial {trial.trial_id}: tare {self.tare_n:+.4f} N over {len(raw_forces)} samples"
        )

    def _move_servos(self, goals: dict[int, float], what: str, speed_rad_s: float) -> None:
        if not goals:
            return
        servos = self.session.servos
        servos.write_goal_positions(goals)
        for sid, goal in goals.items():
            self._command(sid, ServoCommandName.GOAL_POSITION, goal, "rad")
        travel = max(abs(goal - self.states[sid].position_rad) for sid, goal in goals.items())
        timeout = move_timeout_s(travel, speed_rad_s, self.protocol.step_timeout_margin_s)

        def arrived() -> bool:
            return all(
                abs(self.states[sid].position_rad - goal) < _POSITION_TOLERANCE_RAD
                and not self.states[sid].moving
                for sid, goal in goals.items()
            )

        self._wait_until(arrived, timeout, what)

    def _bend(self, trial: TrialPlan) -> None:
        self._phase(Phase.BENDING, trial.trial_id, "bend")
        angles = trial.joint_angles_rad or ()
        goals = self.session.fixture.bend_goals(angles)
        if not goals:
            degrees = ", ".join(f"{math.degrees(a):.1f}" for a in angles)
            self.session.operator.confirm(
                f"Bend the link to configuration {trial.configuration_index}: [{degrees}] deg",
                trial,
                self._tick,
            )
            return
        self._move_servos(goals, "bend", speed_rad_s=_BENDER_SPEED_RAD_S)

    def _reset(self, trial: TrialPlan) -> None:
        self._phase(Phase.RESETTING, trial.trial_id, "reset")
        goals = self.session.fixture.home_goals()
        if not goals:
            self.session.operator.confirm("Straighten the link (reset), then confirm.", trial, self._tick)
            return
        self._move_servos(goals, "reset", speed_rad_s=_BENDER_SPEED_RAD_S)

    def _measure(self, found: TrialMeasurements) -> None:
        source = self.session.configuration
        if source is None:
            return  # the commanded configuration stands for the measured one
        reading = source.measure()
        if reading.joint_angles_rad is not None:
            found.joint_angles_rad = tuple(reading.joint_angles_rad)

    # ------------------------------------------------------------------ ramp

    def _predicted_force_n(self, trial: TrialPlan, found: TrialMeasurements) -> float | None:
        if trial.kind == TrialKind.JOINT_ESTIMATION:
            assert trial.distance_m is not None
            found.predicted_force_n = self.estimator.predict_joint_estimation_force_n(trial.distance_m)
            found.lever_arms_m = None
            return found.predicted_force_n
        prediction = self.estimator.predict_link(found.joint_angles_rad or ())
        if prediction is None:
            raise InterlockTripped("link validation needs joint estimates, and none are available")
        found.predicted_force_n = prediction.slip_force_n
        found.lever_arms_m = prediction.lever_arms_m
        return prediction.slip_force_n

    def _ramp_until_slip(self, trial: TrialPlan, found: TrialMeasurements) -> None:
        ramp = self.protocol.ramp
        winch = self.session.winch_id
        servos = self.session.servos
        predicted = self._predicted_force_n(trial, found)
        switch_n = self.detector_params.arm_threshold_n
        if predicted is not None and math.isfinite(predicted):
            switch_n = max(switch_n, ramp.fast_until_fraction * predicted)
        zero = self.winch_zero_rad
        assert zero is not None
        reel = self.config.reel_direction  # +1: reeling in increases the winch's position
        target = zero + reel * self.config.limits.max_winch_travel_rev * 2 * math.pi
        radius = self.config.spool_radius_m
        # Timeout from the motion: the slow ramp to the protocol's maximum force, with the
        # nominal line stiffness, three times over, plus the margin.
        slow_s = ramp.max_force_n / (self.stiffness_n_per_m * radius * ramp.slow_speed_rad_s)
        timeout_s = 3.0 * slow_s + self.protocol.step_timeout_margin_s
        deadline = self.clock.monotonic_ns() + round(timeout_s * 1e9)

        fast = self.force_n < switch_n
        # The detector sees exactly the samples stamped at or after this instant, which is also the
        # log time of the phase change, so `rig replay` can feed it the very same samples. Those
        # stamped at this very instant came with the last tick: they are fed first.
        ramp_start_ns = self.clock.time_ns()
        stamped_at_start = [(t_ns, force) for t_ns, force in self.tick_samples if t_ns >= ramp_start_ns]
        self._phase(
            Phase.RAMP_FAST if fast else Phase.RAMP_SLOW, trial.trial_id, "ramp_until_slip", ramp_start_ns
        )
        speed = ramp.fast_speed_rad_s if fast else ramp.slow_speed_rad_s
        servos.set_profile(winch, velocity_rad_s=speed)
        goal = self._advance_ramp_goal(target, speed, None)
        params = self.detector_params
        state = detector_init(params)
        event: SlipEvent | None = None
        after_event: list[tuple[int, float]] = []  # samples of the detecting tick after the event
        peak_n = 0.0
        while event is None:
            self._tick()
            samples = stamped_at_start + self.tick_samples
            stamped_at_start = []
            fed = [i for i, (t_ns, _) in enumerate(samples) if t_ns >= ramp_start_ns]
            times = [samples[i][0] for i in fed]
            forces = [samples[i][1] for i in fed]
            j = 0
            while j < len(fed):
                # detector_run: detector_step over the samples until one fires (with a fast path).
                state, k, fired = detector_run(params, state, times, forces, j)
                peak_n = max(peak_n, *forces[j : k + 1])
                if fired is None:
                    break
                if self._confirmed_by_winch(fired):
                    event = fired
                    after_event = samples[fed[k] + 1 :]
                    break
                state = detector_init(params)  # not a slip: start over, so a real one is seen
                j = k + 1
            found.peak_observed_n = peak_n
            if event is not None:
                break
            if fast and self.force_n >= switch_n:
                fast = False
                speed = ramp.slow_speed_rad_s
                servos.set_profile(winch, velocity_rad_s=speed)
                goal = self._advance_ramp_goal(target, speed, None)
                self._phase(Phase.RAMP_SLOW, trial.trial_id, "ramp_until_slip")
            else:
                goal = self._advance_ramp_goal(target, speed, goal)
            if self.force_n >= ramp.max_force_n:
                found.outcome = TrialOutcome.NO_SLIP
                self._note(
                    LogLevel.WARNING, f"trial {trial.trial_id}: no slip up to {ramp.max_force_n:.1f} N"
                )
                break
            if reel * self.states[winch].position_rad >= reel * target - _POSITION_TOLERANCE_RAD:
                found.outcome = TrialOutcome.NO_SLIP
                self._note(LogLevel.WARNING, f"trial {trial.trial_id}: winch travel exhausted without a slip")
                break
            if self.clock.monotonic_ns() > deadline:
                raise StepTimeoutError(
                    f"trial {trial.trial_id}: ramp_until_slip exceeded its timeout of {timeout_s:.1f} s"
                )
        # Stop reeling: hold where the winch is, keep logging the post-slip tension briefly.
        hold = self.states[winch].position_rad
        servos.write_goal_positions({winch: hold})
        self._command(winch, ServoCommandName.GOAL_POSITION, hold, "rad")
        found.peak_observed_n = peak_n
        if event is not None:
            found.event = event
            found.train_drops = self._hold_after_slip(event, state, after_event)
            if self.session.configuration is not None:
                found.slipped_joint = self.session.configuration.measure().slipped_joint
            found.outcome = slip_outcome(trial, event, found.train_drops, found.slipped_joint)
            message = SlipMessage(
                trial.trial_id, event, params.to_mapping(), found.slipped_joint, found.train_drops
            )
            self._log(schemas.SLIP, message.to_payload(), event.detection_time_ns)
            if found.outcome != TrialOutcome.SLIP:
                self._note(LogLevel.INFO, f"trial {trial.trial_id}: {found.outcome} ({_why(found)})")

    def _hold_after_slip(
        self, event: SlipEvent, state: DetectorState, pending: list[tuple[int, float]]
    ) -> int:
        """Hold the winch for `hold_after_slip_s`, logging; the further drops the detector counts in it.

        The detector, latched by the event, is stepped over the samples up to `hold_after_slip_s`
        after the detection (a window of sample times, so that replay picks the same samples).
        """
        hold_s = self.protocol.ramp.hold_after_slip_s
        end_ns = event.detection_time_ns + round(hold_s * 1e9)
        samples = list(pending)
        stop = self.clock.monotonic_ns() + round(hold_s * 1e9)
        while self.clock.monotonic_ns() < stop:
            self._tick()
            samples += self.tick_samples
        window = [(t_ns, force) for t_ns, force in samples if t_ns <= end_ns]
        _, drops = further_drops(self.detector_params, state, [t for t, _ in window], [f for _, f in window])
        return drops

    def _advance_ramp_goal(self, limit_rad: float, speed_rad_s: float, goal_rad: float | None) -> float:
        """Keep the winch's goal a short way ahead of it, never the far end of its travel.

        The goal leads the winch by `RAMP_GOAL_LEAD_S` of motion and is moved on once the winch is
        halfway there. If the host stops talking (crash, lost link), the winch stops within that
        lead instead of reeling on to `limit_rad`. A goal of None sets the first one.
        """
        winch = self.session.winch_id
        reel = self.config.reel_direction  # reel-in coordinates: the sign times the position
        position = reel * self.states[winch].position_rad
        lead = speed_rad_s * RAMP_GOAL_LEAD_S
        if goal_rad is not None and (
            reel * goal_rad >= reel * limit_rad or reel * goal_rad - position > lead / 2
        ):
            return goal_rad
        goal = reel * min(reel * limit_rad, position + lead)
        self.session.servos.write_goal_positions({winch: goal})
        self._command(winch, ServoCommandName.GOAL_POSITION, goal, "rad")
        return goal

    def _log_links(self, links: TrialLinkStats) -> None:
        """Log the trial's link counts, and what the load cell lost as a note (a warning if anything)."""
        self._log(schemas.TRIAL_LINKS, links.to_payload())
        lines = links.loadcell
        if lines is not None:
            level = LogLevel.INFO if lines.lossless else LogLevel.WARNING
            self._note(level, f"trial {links.trial_id}: load cell {lines.describe()}")

    def _confirmed_by_winch(self, event: SlipEvent) -> bool:
        """A tension drop is a slip only if the winch was not backing off (it reels in or holds)."""
        winch = self.states.get(self.session.winch_id)
        if winch is None or winch.hardware_error:
            return False
        confirmed = self.config.reel_direction * winch.velocity_rad_s > -0.05
        if not confirmed:
            self._note(LogLevel.WARNING, f"drop at {event.peak_force_n:.2f} N ignored: winch was backing off")
        return confirmed

    # ------------------------------------------------------------------ releasing the line

    def _unload(self, trial: TrialPlan) -> None:
        self._phase(Phase.UNLOADING, trial.trial_id, "unload")
        self._release_tension()

    def _release_tension(self) -> None:
        """The unload step: back the winch off to its zero-tension angle with the interlocks live.

        It waits until the winch is home and the load cell reads the line slack. The safe state's
        release, which must not depend on the load cell or on replies, is `_release_in_safe_state`.
        """
        winch = self.session.winch_id
        zero = self.winch_zero_rad
        if zero is None:
            return
        servos = self.session.servos
        speed = self.protocol.ramp.unload_speed_rad_s
        servos.set_profile(winch, velocity_rad_s=speed)
        servos.write_goal_positions({winch: zero})
        self._command(winch, ServoCommandName.GOAL_POSITION, zero, "rad")

        def done() -> bool:
            home = abs(self.states[winch].position_rad - zero) < _POSITION_TOLERANCE_RAD
            return home and self.force_n < _RELEASED_TENSION_N + abs(self.tare_n)

        travel = self.states[winch].position_rad - zero
        self._wait_until(done, move_timeout_s(travel, speed, self.protocol.step_timeout_margin_s), "unload")

    def _release_in_safe_state(self, zero_rad: float) -> float:
        """The safe state's release: whatever failed, get the winch back to zero tension if it hears.

        Each stage goes on when an earlier one failed, and what was verified is recorded in
        `self.release_report`: a winch with a latched hardware error is rebooted first (its turn
        count is lost, so the zero is carried over into the new count); the goal goes out as a
        broadcast sync write, which needs no reply; the wait reads the winch's position back, and
        if the winch stops answering it waits the travel time blind. The load cell is optional.
        Returns the winch's zero-tension angle in its (possibly new) turn count.
        """
        winch = self.session.winch_id
        servos = self.session.servos
        report = self.release_report
        zero_rad = self._recover_winch(zero_rad)
        speed = self.protocol.ramp.unload_speed_rad_s
        try:
            servos.set_profile(winch, velocity_rad_s=speed)
        except RigError as exc:
            # The profile in force is one the ramp set: wait as long as the slowest would take.
            speed = min(speed, self.protocol.ramp.slow_speed_rad_s, self.protocol.ramp.fast_speed_rad_s)
            report.append(f"release speed not confirmed ({exc})")
        servos.write_goal_positions({winch: zero_rad})
        self._command(winch, ServoCommandName.GOAL_POSITION, zero_rad, "rad")
        last = self.states.get(winch)
        travel = abs(last.position_rad - zero_rad) if last is not None else 2 * math.pi
        wait_s = move_timeout_s(travel, speed, _SAFE_STATE_MARGIN_S)
        deadline = self.clock.monotonic_ns() + round(wait_s * 1e9)
        answered = False
        while self.clock.monotonic_ns() < deadline:
            try:
                self._tick_without_interlocks()
            except RigError:
                self.clock.sleep(self.protocol.control_period_s)  # not answering: wait out the travel
                continue
            answered = True
            if abs(self.states[winch].position_rad - zero_rad) < _POSITION_TOLERANCE_RAD:
                self.release_verified = True
                report.append("winch back at its zero-tension angle (read back)")
                if self.tick_samples:  # the load cell, when it still works, says what is left
                    report.append(f"tension {self.force_n:+.2f} N (load cell)")
                return zero_rad
        if answered:
            raise StepTimeoutError("winch did not return to zero tension within its timeout")
        report.append(
            f"winch not answering: its zero-tension goal went out by broadcast; it was given {wait_s:.1f} s"
            " (not verified)"
        )
        return zero_rad

    def _recover_winch(self, zero_rad: float) -> float:
        """Reboot a winch whose hardware error dropped its torque; the zero-tension angle after it.

        A reboot folds the multi-turn position into one turn, and the shaft does not move while
        its torque is off, so the turns lost are the difference of the positions before and after.
        """
        winch = self.session.winch_id
        state = self.states.get(winch)
        if state is None or not state.hardware_error:
            return zero_rad
        servos = self.session.servos
        servos.reboot(winch)
        self.states = servos.read_states()
        turns = round((state.position_rad - self.states[winch].position_rad) / (2 * math.pi))
        self.release_report.append(f"winch rebooted after hardware error 0x{state.hardware_error:02X}")
        return zero_rad - turns * 2 * math.pi

    def _tick_without_interlocks(self) -> None:
        """One control period of the safe state: read the servos and log; the load cell is optional.

        The load cell may be what failed (stale, unplugged, a port error): the release goes on
        without it, since only the winch's position is waited for.
        """
        self.clock.sleep(self.protocol.control_period_s)
        self.states = self.session.servos.read_states()
        try:
            samples = self.session.load_cell.poll()
        except Exception:  # whatever the load cell's failure, the line still has to be released
            samples = []
        self._ingest(samples)

    # ------------------------------------------------------------------ safety

    def _make_safe(self) -> str | None:
        """Release the line, then torque off every servo, then close; an error text, or None if verified.

        Says what was verified, never what was only attempted: the release is verified when the
        winch's position was read back at its zero-tension angle, the torque-off when every servo
        confirmed it.
        """
        self.release_report = []
        self.release_verified = not self.connected or self.winch_zero_rad is None  # never loaded

        def release() -> None:
            if self.release_verified or self.winch_zero_rad is None:
                return
            self._phase_quiet(Phase.UNLOADING)
            self._release_in_safe_state(self.winch_zero_rad)

        with self._logging_best_effort():
            errors = enter_safe_state(self.session, release)
            done = "; ".join(self.release_report)
            if not errors and self.release_verified:
                self._note(
                    LogLevel.INFO, "safe state: " + (done + "; " if done else "") + "torque off (confirmed)"
                )
                return None
            problem = "; ".join(p for p in (done, *errors) if p)
            if not self.release_verified or any(e.startswith("torque off failed") for e in errors):
                problem += f" — {LINE_MAY_BE_LOADED}"
            self._note(LogLevel.ERROR, "safe state not verified: " + problem)
            return problem

    # ------------------------------------------------------------------ logging

    def _log(self, topic: str, payload: dict[str, object], time_ns: int | None = None) -> None:
        if self._log_failed is not None:
            return
        try:
            self.log.log(topic, self.clock.time_ns() if time_ns is None else time_ns, payload)
        except LogWriteError as exc:
            self._logger_failed(exc)

    def _logger_failed(self, exc: LogWriteError) -> None:
        """The log cannot be written: stop logging; outside the safe state, stop the run (a fault)."""
        self._log_failed = exc
        self.progress.message(f"log write failed, logging stopped: {exc}")
        if not self._best_effort:
            raise exc

    @contextlib.contextmanager
    def _logging_best_effort(self) -> Iterator[None]:
        """Inside, a failing log never stops the rig: the first failure ends logging (the safe state)."""
        self._best_effort = True
        try:
            yield
        finally:
            self._best_effort = False

    def _command(self, servo_id: int, command: ServoCommandName, value: float | None, unit: str) -> None:
        role = self.session.roles.get(servo_id, "")
        self._log(schemas.SERVO_COMMAND, ServoCommand(servo_id, role, command, value, unit).to_payload())

    def _phase(
        self, phase: Phase, trial_id: int | None, step: str | None = None, at_ns: int | None = None
    ) -> None:
        if self.phases.to(phase):
            self._log(schemas.TRIAL_STATE, TrialState(trial_id, phase, step).to_payload(), at_ns)

    def _phase_quiet(self, phase: Phase) -> None:
        """Best-effort phase change during cleanup (never raises)."""
        with contextlib.suppress(RuntimeError):
            self._phase(phase, self.trial.trial_id if self.trial else None, "safe_state")

    def _note(self, level: LogLevel, text: str) -> None:
        # The log itself may be what failed; the progress line below still tells.
        with contextlib.suppress(Exception):
            now = self.clock.time_ns()
            self._log(schemas.LOG, LogMessage(now, level, text).to_payload(), now)
        if level >= LogLevel.WARNING:
            self.progress.message(text)

    @staticmethod
    def _describe(trial: TrialPlan) -> str:
        if trial.kind == TrialKind.JOINT_ESTIMATION:
            return f"joint {trial.joint} at {trial.distance_m:.3f} m (repeat {trial.repeat})"
        return f"configuration {trial.configuration_index} (repeat {trial.repeat})"


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
