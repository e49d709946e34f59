"""The trial loop: runs a protocol's trials on a rig session, logging and refitting online.

The parts, one job each: the control loop ticks (`rig.runner.control_loop`: read, log, interlocks,
waits); each step of the protocol's per-trial template is a function in the table
`rig.runner.steps.STEPS` (the ramp, with its winch drive and detector feed, is
`rig.runner.ramp`); the recorder writes phases, commands and notes (`rig.runner.recorder`); the
release after a failure keeps its own state (`rig.safety.release`). This module connects the rig,
runs each trial (repeating it after a device fault that clears) and ends the run.

Whatever ends the run (success, interlock, fault, exception, Ctrl-C), `run()` finishes in the safe
state: line tension released, then torque off, inside a block that a second Ctrl-C cannot
interrupt, then the log is finished and the journal saved. The stages of the safe state are
`rig.safety.safe_state`; the trial's record is built by `rig.runner.results`.
"""

from __future__ import annotations

import traceback
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import assert_never

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
from rig.hw.seams import OperatingMode
from rig.hw.session import RigSession
from rig.inputs.protocol import Protocol, TrialPlan
from rig.inputs.rig_config import RigConfig, nominal_loadcell_rate_hz
from rig.log.format import schemas
from rig.records import LogLevel, ServoCommandName, TrialOutcome, TrialPhase, TrialResult, TrialWireStats
from rig.runner.control_loop import ControlLoop
from rig.runner.journal import RunJournal
from rig.runner.link_view import LinkView
from rig.runner.loaded_at_connect import PayoutVerdict, pay_out_verified
from rig.runner.recorder import RunRecorder
from rig.runner.recovery import MAX_TRIAL_RETRIES, is_device_fault, recover
from rig.runner.results import TrialMeasurements, nothing_measured, trial_result
from rig.runner.run_estimates import RunEstimator
from rig.runner.sinks import RunSink
from rig.runner.step_context import BENDER_SPEED_RAD_S, StepContext
from rig.runner.steps import STEPS
from rig.runner.wire_counts import TrialWireCounter
from rig.safety.interlocks import CurrentAtLimit, ForceCeiling
from rig.safety.interrupts import interrupts_held
from rig.safety.release import LineRelease
from rig.safety.safe_state import enter_safe_state
from rig.vocabulary import ServoRole, TrialKind

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
        sinks: Sequence[RunSink],
        journal: RunJournal,
        estimator: RunEstimator,
        line_stiffness_n_per_m: float,
    ) -> None:
        self.protocol = protocol
        self.config = config
        self.session = session
        self.clock = session.clock
        self.journal = journal
        self.estimator = estimator
        self.recorder = RunRecorder(sinks, session.clock, session.roles)
        ceiling = config.limits.force_ceiling_n
        if protocol.force_ceiling_n is not None:
            ceiling = min(ceiling, protocol.force_ceiling_n)
        self.loop = ControlLoop(
            session,
            self.recorder,
            period_s=protocol.control_period_s,
            ceiling=ForceCeiling(ceiling),
            current_limit=CurrentAtLimit(session.winch_id, config.limits.winch_current_limit_a, hold_s=1.0),
        )
        self.ctx = StepContext(
            protocol=protocol,
            config=config,
            session=session,
            loop=self.loop,
            recorder=self.recorder,
            estimator=estimator,
            detector_params=protocol.detector,
            line_stiffness_n_per_m=line_stiffness_n_per_m,
            link_view=LinkView(self.recorder, config.article),
            loadcell_rate_hz=nominal_loadcell_rate_hz(config),
        )
        self.trial: TrialPlan | None = None
        self.connected = False
        # Set by the safe state when it was verified without the load cell (it gave no reading).
        self.tension_unmeasured: str | None = None

    # ------------------------------------------------------------------ run

    def run(self, trials: Iterable[TrialPlan]) -> RunOutcome:
        """Run `trials` in order and always end safe; returns the exit code and status.

        `trials` may be lazy (`rig.runner.planning.TrialSchedule`): the next trial is asked for only
        after the previous one is journalled.
        """
        note = self.recorder.note
        outcome = RunOutcome(ExitCode.OK, "completed")
        try:
            self._connect()
            for trial in trials:
                outcome.new_results.append(self._run_trial_until_done(trial))
            self.recorder.phase(TrialPhase.DONE, None)
        except KeyboardInterrupt:
            outcome = RunOutcome(
                ExitCode.INTERRUPTED, "interrupted", "interrupted by the operator", outcome.new_results
            )
            note(LogLevel.WARNING, "interrupted: releasing the line and turning torque off")
        except RigError as exc:
            outcome = RunOutcome(
                ExitCode.FAULT, "faulted", f"{type(exc).__name__}: {exc}", outcome.new_results
            )
            note(LogLevel.ERROR, f"run stopped: {exc}")
        except Exception as exc:  # a bug must still end in the safe state, and be reported
            outcome = RunOutcome(ExitCode.FAULT, "faulted", f"internal error: {exc!r}", outcome.new_results)
            note(LogLevel.FATAL, "internal error: " + "".join(traceback.format_exception(exc)))
        finally:
            # Held, not re-raised after: the outcome is decided, and the caller must still save it.
            with interrupts_held() as late:
                safe_error = self._make_safe()
                if safe_error is not None:  # never hidden behind the reason the run stopped for
                    reason = safe_error if outcome.reason is None else f"{outcome.reason}; then {safe_error}"
                    exit_code = ExitCode.FAULT if outcome.exit_code == ExitCode.OK else outcome.exit_code
                    status = "faulted" if outcome.exit_code == ExitCode.OK else outcome.status
                    outcome = RunOutcome(exit_code, status, reason, outcome.new_results, False)
                elif self.tension_unmeasured is not None and outcome.reason is not None:
                    outcome.reason = f"{outcome.reason}; then {self.tension_unmeasured}"
                if outcome.exit_code != ExitCode.OK and self.recorder.phases.phase not in (
                    TrialPhase.ABORTED,
                    TrialPhase.FAULTED,
                ):
                    self.recorder.phase(
                        TrialPhase.ABORTED
                        if outcome.exit_code == ExitCode.INTERRUPTED
                        else TrialPhase.FAULTED,
                        None,
                    )
                if late:
                    note(LogLevel.WARNING, "Ctrl-C/SIGTERM in the safe state: held until it ended")
        if outcome.exit_code == ExitCode.OK:  # every trial done: did the run measure anything?
            nothing = nothing_measured(self.journal.completed, self.protocol.ramp.max_force_n)
            if nothing is not None:
                note(LogLevel.ERROR, f"run measured nothing: {nothing}")
                outcome = RunOutcome(
                    ExitCode.FAULT, "completed", nothing, outcome.new_results, outcome.safe_state_verified
                )
        return outcome

    def announce(self, text: str, warning: bool = False) -> None:
        """A line for the log (`/rig/log`, INFO or WARNING) that the progress display shows too."""
        self.recorder.announce(text, warning)

    def _connect(self) -> None:
        recorder = self.recorder
        recorder.phase(TrialPhase.CONNECTING, None)
        servos = self.session.servos
        servos.connect()
        self.connected = True
        self.loop.check_port_latency()
        winch = self.session.winch_id
        servos.set_current_limit(winch, self.config.limits.winch_current_limit_a)
        servos.set_operating_mode(
            winch,
            OperatingMode.CURRENT_BASED_POSITION,
            goal_current_a=self.config.limits.winch_current_limit_a,
            profile_velocity_rad_s=self.protocol.ramp.fast_speed_rad_s,
        )
        recorder.command(winch, ServoCommandName.MODE, float(OperatingMode.CURRENT_BASED_POSITION), "")
        benders = [sid for sid, role in self.session.roles.items() if role == ServoRole.BENDER]
        for sid in benders:
            servos.set_operating_mode(
                sid, OperatingMode.EXTENDED_POSITION, profile_velocity_rad_s=BENDER_SPEED_RAD_S
            )
            recorder.command(sid, ServoCommandName.MODE, float(OperatingMode.EXTENDED_POSITION), "")
        servos.set_torque([winch, *benders], True)
        for sid in (winch, *benders):
            recorder.command(sid, ServoCommandName.TORQUE, 1.0, "")
        self.session.load_cell.open()
        self.loop.restart_pacing()
        self.loop.tick(interlocks=False)
        while not self.loop.tick_samples:  # a slow cell: the driver raises StaleDataError if none come
            self.loop.tick(interlocks=False)
        self.ctx.winch_zero_rad = self.loop.states[winch].position_rad
        self._verify_zero()
        self.loop.check_interlocks()
        recorder.phase(TrialPhase.IDLE, None)
        recorder.note(
            LogLevel.INFO,
            f"connected: servos {sorted(self.session.roles)}; winch zero {self.ctx.winch_zero_rad:.4f} rad",
        )

    def _verify_zero(self) -> None:
        """Refuse to take a loaded line as zero: the cell must read within the tolerance of its zero.

        Called at connect, after the first samples and before anything has moved. Beyond the
        tolerance the line may be loaded (a stop that could not release it) or the calibration's
        zero is off; either way the run stops (exit 1) with the reading. A positive reading is paid
        out in small steps, each checked on the cell (`rig.runner.loaded_at_connect`): never by a
        travel in a direction nobody has verified yet; the payout sets the winch's zero-tension angle
        (`pay_out_verified`). The safe state's load-cell check then says whether the line ended slack.
        """
        samples = [s.force_n for s in self.loop.tick_samples]
        reading_n = sum(samples) / len(samples)
        limits = self.config.limits
        if abs(reading_n) <= limits.zero_tolerance_n:
            return
        beyond = (
            f"the load cell reads {reading_n:+.2f} N at connect, beyond limits.zero_tolerance_n "
            f"({limits.zero_tolerance_n:g} N) of its calibrated zero"
        )
        if reading_n < 0:  # a line cannot push: the cell's zero is off, and nothing needs to move
            raise ZeroNotVerified(
                f"{beyond}; a line cannot push, so the cell's zero is off: nothing moved. Recalibrate the "
                "load cell with `rig calibrate` and start the run again"
            )
        payout = pay_out_verified(self.ctx, reading_n)  # it leaves the zero where the winch holds
        if payout.verdict == PayoutVerdict.SLACK and payout.reversed:
            fix = (
                f"on the now slack line run `rig check --rig {self.config.source} --move --write` to "
                "measure reel_direction, then start the run again"
            )
        elif payout.verdict == PayoutVerdict.SLACK:
            fix = "if the line is slack now, start the run again"
        else:
            fix = (
                "slacken the line by hand (servo power off), check reel_direction with `rig check --move` "
                "on the slack line, and start the run again (if the line is slack, recalibrate the load cell "
                "with `rig calibrate`)"
            )
        raise ZeroNotVerified(f"{beyond}, so the line may be loaded: {payout.describe()}; {fix}")

    # ------------------------------------------------------------------ trial

    def _run_trial_until_done(self, trial: TrialPlan) -> TrialResult:
        """Run a trial; after a device fault that clears, repeat it (at most `MAX_TRIAL_RETRIES` times).

        A device fault (a servo or load cell not answering, stale data, a latched hardware error)
        stops the attempt in a trial-level safe state (`rig.runner.recovery`). If the rig recovers
        within `limits.recovery_grace_s`, the trial starts again from its first step; the retry is logged
        and counted in the journal. Otherwise the fault ends the run (exit 1).
        """
        links = TrialWireCounter(self.session, self.loop.take_tick_stats)  # over every attempt
        for retries in range(MAX_TRIAL_RETRIES + 1):
            try:
                return self._run_trial(trial, links)
            except (
                StaleDataError,
                NotConnectedError,
                CommunicationError,
                RigTimeoutError,
                HardwareFault,
                InterlockTripped,
            ) as exc:
                if (
                    retries == MAX_TRIAL_RETRIES
                    or not is_device_fault(exc, self.loop.states)
                    or not recover(self.ctx, trial, exc)
                ):
                    # The run ends here: the trial's link counts (late ticks, bus timeouts) still go
                    # in the log, as they say what the host and the bus were doing when it failed.
                    with self.recorder.best_effort():
                        self._log_links(links.finish(trial.trial_id))
                    raise
            self.journal.record_retry(trial.trial_id)
            self.recorder.note(
                LogLevel.WARNING, f"trial {trial.trial_id}: the rig recovered; repeating the trial"
            )
        raise AssertionError("unreachable")

    def _run_trial(self, trial: TrialPlan, links: TrialWireCounter) -> TrialResult:
        self.trial = trial
        start_ns = self.clock.time_ns()
        self.recorder.trial_started(trial.trial_id, _describe(trial))
        found = TrialMeasurements(joint_angles_rad=trial.joint_angles_rad)
        try:
            for step in trial.steps:
                STEPS[step.kind](self.ctx, step, trial, found)
        except StepTimeoutError as exc:
            self._abort_trial(trial, found, exc)
        self._log_links(links.finish(trial.trial_id))
        result = trial_result(
            trial,
            found,
            start_time_ns=start_ns,
            end_time_ns=self.clock.time_ns(),
            tare_n=self.loop.tare_n,
            g=self.config.article.g,
        )
        self.estimator.apply_result(result)
        estimate = self.estimator.estimate(trial.trial_id)
        log_time = self.clock.time_ns()
        self.ctx.link_view.show(trial, found, found.peak_observed_n or 0.0, log_time)
        self.recorder.write(schemas.TRIAL_RESULT, result.to_payload(), log_time)
        self.recorder.write(schemas.ESTIMATE, estimate.to_payload(), log_time)
        self.recorder.flush()
        self.journal.record_trial(result)
        self.recorder.trial_finished(result, estimate)
        return result

    def _abort_trial(self, trial: TrialPlan, found: TrialMeasurements, exc: StepTimeoutError) -> None:
        """A step timed out: release the line and, if the rig is healthy, record the trial as aborted.

        The run goes on with the next trial. If the line cannot be released or the rig does not
        answer healthily within `limits.recovery_grace_s`, the timeout ends the run (exit 1).
        """
        if not recover(self.ctx, trial, exc):
            raise exc
        found.outcome = TrialOutcome.ABORTED
        found.reason = str(exc)
        self.recorder.note(LogLevel.WARNING, f"trial {trial.trial_id}: aborted ({exc}); the run goes on")

    def _log_links(self, links: TrialWireStats) -> None:
        """Log the trial's link counts; late control ticks and what the load cell lost as notes."""
        self.recorder.write(schemas.TRIAL_LINKS, links.to_payload())
        ticks = links.control
        if ticks is not None and ticks.late_ticks:
            self.recorder.note(
                LogLevel.WARNING,
                f"trial {links.trial_id}: {ticks.late_ticks} of {ticks.ticks} control ticks started late, "
                f"the latest by {ticks.max_lateness_us / 1000:.1f} ms"
                + (f": {self.loop.lateness_cause()}" if self.loop.slow_latency_timer_ms is not None else ""),
            )
        bus = links.bus
        if bus is not None and bus.timeouts and self.loop.slow_latency_timer_ms is not None:
            self.recorder.note(
                LogLevel.WARNING,
                f"trial {links.trial_id}: {bus.timeouts} servo bus timeouts in {bus.operations} operations: "
                + self.loop.lateness_cause(),
            )
        lines = links.loadcell
        if lines is not None:
            level = LogLevel.INFO if lines.lossless else LogLevel.WARNING
            self.recorder.note(level, f"trial {links.trial_id}: load cell {lines.describe()}")

    # ------------------------------------------------------------------ safety

    def _make_safe(self) -> str | None:
        """Release the line, then torque off every servo, then close; an error text, or None if verified.

        Says what was verified, never what was only attempted: the release is verified when the
        winch's position was read back at its zero-tension angle and the load cell read the line
        slack there (or gave no reading at all, which the report says), the torque-off when every
        servo confirmed it.
        """
        zero = self.ctx.winch_zero_rad
        never_loaded = not self.connected or zero is None
        releases: list[LineRelease] = []

        def release() -> None:
            if never_loaded or zero is None:
                return
            self.recorder.phase_quiet(TrialPhase.UNLOADING, self.trial.trial_id if self.trial else None)
            releases.append(self.ctx.line_release())
            try:
                releases[0].run(zero)
                releases[0].confirm_slack(self.config.limits.zero_tolerance_n)
            finally:
                self.loop.adopt(releases[0].reading())

        with self.recorder.best_effort():
            errors = enter_safe_state(self.session, release)
            done = "; ".join(releases[0].report if releases else [])
            verified = never_loaded or (bool(releases) and releases[0].slack_confirmed)
            if not errors and verified:
                if releases and not releases[0].tension_measured:
                    self.tension_unmeasured = f"safe state: {done}; torque off (confirmed)"
                self.recorder.note(
                    LogLevel.INFO, "safe state: " + (done + "; " if done else "") + "torque off (confirmed)"
                )
                return None
            problem = "; ".join(p for p in (done, *errors) if p)
            if not verified or any(e.startswith("torque off failed") for e in errors):
                problem += f" — {LINE_MAY_BE_LOADED}"
            self.recorder.note(LogLevel.ERROR, "safe state not verified: " + problem)
            return problem


def _describe(trial: TrialPlan) -> str:
    """The trial in a few words, for the progress display."""
    match trial.kind:
        case TrialKind.JOINT_ESTIMATION:
            return f"joint {trial.joint} at {trial.distance_m:.3f} m (repeat {trial.repeat})"
        case TrialKind.LINK_VALIDATION:
            return f"configuration {trial.configuration_index} (repeat {trial.repeat})"
        case kind:
            assert_never(kind)
