"""The trial loop: runs a protocol's trials on a rig session, logging everything and refitting online.

One control tick reads the servo states (one sync read), drains the load cell (never blocking),
logs both, checks the interlocks, and hands the samples to the step in progress. Steps are small
methods (tare, bend, measure, prompt, ramp_until_slip, unload, reset, pause) driven by the
protocol's per-trial template. Whatever ends the run (success, interlock, fault, exception,
Ctrl-C), `run()` finishes in the safe state: line tension released, then torque off, inside a
block that a second Ctrl-C cannot interrupt, then the log is finished and the journal saved.
"""

from __future__ import annotations

import contextlib
import math
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from model.payload_errors import payload_error_stats
from model.slip_detector import DetectorParams, SlipEvent, detector_init, detector_step
from rig.errors import (
    HardwareFault,
    InterlockTripped,
    RigError,
    RigTimeoutError,
    StaleDataError,
)
from rig.hw.seams import LoadCellSample, OperatingMode, ServoState
from rig.hw.session import RigSession
from rig.log import schemas
from rig.log.schemas import LogLevel
from rig.log.writer import RunLogger
from rig.protocol import Protocol, StepSpec, TrialPlan
from rig.rig_config import RigConfig
from rig.runner.estimation import RunEstimator
from rig.runner.interlocks import CurrentAtLimit, ForceCeiling, ServoHealth
from rig.runner.journal import RunJournal
from rig.runner.phases import Phase, PhaseMachine
from rig.runner.progress import ProgressReporter
from rig.runner.safety import interrupts_deferred

EXIT_OK, EXIT_FAULT, EXIT_INTERRUPTED = 0, 1, 130
_POSITION_TOLERANCE_RAD = 0.02
_RELEASED_TENSION_N = 0.5


@dataclass
class RunOutcome:
    """How a run invocation ended."""

    exit_code: int
    status: str  # journal status: completed, faulted, interrupted
    reason: str | None = None
    new_results: list[dict[str, Any]] = field(default_factory=list)


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
    ) -> None:
        self.protocol = protocol
        self.config = config
        self.session = session
        self.clock = session.clock
        self.log = logger
        self.journal = journal
        self.estimator = estimator
        self.progress = progress
        self.stiffness_n_per_m = line_stiffness_n_per_m
        self.detector_params = DetectorParams.from_mapping(protocol.detector, source=str(protocol.source))
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

    # ------------------------------------------------------------------ run

    def run(self, trials: list[TrialPlan]) -> RunOutcome:
        """Run `trials` in order and always end safe; returns the exit code and status."""
        outcome = RunOutcome(EXIT_OK, "completed")
        try:
            self._connect()
            for trial in trials:
                outcome.new_results.append(self._run_trial(trial))
            self._phase(Phase.DONE, None)
        except KeyboardInterrupt:
            outcome = RunOutcome(
                EXIT_INTERRUPTED, "interrupted", "interrupted by the operator", outcome.new_results
            )
            self._note(LogLevel.WARNING, "interrupted: releasing the line and turning torque off")
        except (InterlockTripped, StaleDataError, HardwareFault, RigTimeoutError) as exc:
            outcome = RunOutcome(EXIT_FAULT, "faulted", f"{type(exc).__name__}: {exc}", outcome.new_results)
            self._note(LogLevel.ERROR, f"run stopped: {exc}")
        except RigError as exc:
            outcome = RunOutcome(EXIT_FAULT, "faulted", f"{type(exc).__name__}: {exc}", outcome.new_results)
            self._note(LogLevel.ERROR, f"run stopped: {exc}")
        except Exception as exc:  # a bug must still end in the safe state, and be reported
            outcome = RunOutcome(EXIT_FAULT, "faulted", f"internal error: {exc!r}", outcome.new_results)
            self._note(LogLevel.FATAL, "internal error: " + "".join(traceback.format_exception(exc)))
        finally:
            with interrupts_deferred():
                safe_error = self._make_safe()
                if safe_error is not None and outcome.exit_code == EXIT_OK:
                    outcome = RunOutcome(EXIT_FAULT, "faulted", safe_error, outcome.new_results)
                if outcome.exit_code != EXIT_OK and self.phases.phase not in (Phase.ABORTED, Phase.FAULTED):
                    self._phase(
                        Phase.ABORTED if outcome.exit_code == EXIT_INTERRUPTED else Phase.FAULTED, None
                    )
        return outcome

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
        self._command(winch, "mode", float(OperatingMode.CURRENT_BASED_POSITION), "")
        benders = [sid for sid, role in self.session.roles.items() if role == "bender"]
        for sid in benders:
            servos.set_operating_mode(sid, OperatingMode.EXTENDED_POSITION, profile_velocity_rad_s=2.0)
            self._command(sid, "mode", float(OperatingMode.EXTENDED_POSITION), "")
        servos.set_torque([winch, *benders], True)
        for sid in (winch, *benders):
            self._command(sid, "torque", 1.0, "")
        self.session.load_cell.open()
        self._next_tick_ns = self.clock.monotonic_ns()
        self._tick()
        self.winch_zero_rad = self.states[winch].position_rad
        self._phase(Phase.IDLE, None)
        self._note(
            LogLevel.INFO,
            f"connected: servos {sorted(self.session.roles)}; winch zero {self.winch_zero_rad:.4f} rad",
        )

    # ------------------------------------------------------------------ ticks

    def _tick(self) -> None:
        """One control period: wait, read everything, log it, check the interlocks."""
        self._next_tick_ns += self.period_ns
        now = self.clock.monotonic_ns()
        if self._next_tick_ns > now:
            self.clock.sleep((self._next_tick_ns - now) / 1e9)
        else:
            self._next_tick_ns = now  # late: do not try to catch up with a burst of ticks
        self.states = self.session.servos.read_states()
        samples = self.session.load_cell.poll()
        self._ingest(samples)
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

    def _ticks_for(self, seconds: float) -> None:
        end = self.clock.monotonic_ns() + round(seconds * 1e9)
        while self.clock.monotonic_ns() < end:
            self._tick()

    def _wait_until(self, done: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = self.clock.monotonic_ns() + round(timeout_s * 1e9)
        while not done():
            if self.clock.monotonic_ns() > deadline:
                raise RigTimeoutError(f"step {what} did not finish within its timeout of {timeout_s:.1f} s")
            self._tick()

    # ------------------------------------------------------------------ trial

    def _run_trial(self, trial: TrialPlan) -> dict[str, Any]:
        self.trial = trial
        self.session.begin_trial(trial)
        start_ns = self.clock.time_ns()
        self.progress.trial_started(trial.trial_id, self._describe(trial))
        ctx: dict[str, Any] = {"angles": trial.joint_angles_rad, "slipped_joint": None}
        for step in trial.steps:
            self._run_step(step, trial, ctx)
        result = self._result(trial, ctx, start_ns)
        self.estimator.apply_result(result)
        log_time = self.clock.time_ns()
        self.log.log(schemas.TRIAL_RESULT, log_time, self._result_payload(result))
        self.log.log(schemas.ESTIMATE, log_time, self._estimate_payload(trial.trial_id))
        self.log.flush(wait=True)
        self.journal.record_trial(result)
        self.progress.trial_finished(result, self.estimator.estimate_text())
        return result

    def _run_step(self, step: StepSpec, trial: TrialPlan, ctx: dict[str, Any]) -> None:
        kind = step.kind
        if kind == "prompt":
            self._phase(Phase.PROMPTING, trial.trial_id, "prompt")
            self.session.operator.confirm(trial.prompt_text(step.text or ""), trial)
        elif kind == "tare":
            self._tare(step.duration_s, trial)
        elif kind == "bend":
            self._bend(trial, ctx)
        elif kind == "measure":
            self._measure(trial, ctx)
        elif kind == "ramp_until_slip":
            self._ramp_until_slip(trial, ctx)
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
        self.tare_n = sum(raw_forces) / len(raw_forces)
        self._note(
            LogLevel.INFO, f"trial {trial.trial_id}: tare {self.tare_n:+.4f} N over {len(raw_forces)} samples"
        )

    def _move_servos(self, goals: dict[int, float], what: str, speed_rad_s: float) -> None:
        if not goals:
            return
        servos = self.session.servos
        servos.write_goal_positions(goals)
        for sid, goal in goals.items():
            self._command(sid, "goal_position", goal, "rad")
        travel = max(abs(goal - self.states[sid].position_rad) for sid, goal in goals.items())
        timeout = travel / speed_rad_s * 2.0 + self.protocol.step_timeout_margin_s

        def arrived() -> bool:
            return all(
                abs(self.states[sid].position_rad - goal) < _POSITION_TOLERANCE_RAD
                and not self.states[sid].moving
                for sid, goal in goals.items()
            )

        self._wait_until(arrived, timeout, what)

    def _bend(self, trial: TrialPlan, ctx: dict[str, Any]) -> None:
        self._phase(Phase.BENDING, trial.trial_id, "bend")
        angles = trial.joint_angles_rad or ()
        goals = self.session.fixture.bend_goals(angles)
        if not goals:
            degrees = ", ".join(f"{math.degrees(a):.1f}" for a in angles)
            self.session.operator.confirm(
                f"Bend the link to configuration {trial.configuration_index}: [{degrees}] deg", trial
            )
            return
        self._move_servos(goals, "bend", speed_rad_s=2.0)

    def _reset(self, trial: TrialPlan) -> None:
        self._phase(Phase.RESETTING, trial.trial_id, "reset")
        goals = self.session.fixture.home_goals()
        if not goals:
            self.session.operator.confirm("Straighten the link (reset), then confirm.", trial)
            return
        self._move_servos(goals, "reset", speed_rad_s=2.0)

    def _measure(self, trial: TrialPlan, ctx: dict[str, Any]) -> None:
        source = self.session.configuration
        if source is None:
            return  # the commanded configuration stands for the measured one
        reading = source.measure()
        if reading.joint_angles_rad is not None:
            ctx["angles"] = tuple(reading.joint_angles_rad)

    # ------------------------------------------------------------------ ramp

    def _predicted_force_n(self, trial: TrialPlan, ctx: dict[str, Any]) -> float | None:
        if trial.kind == "joint_estimation":
            assert trial.distance_m is not None
            force = self.estimator.predict_joint_estimation_force_n(trial.distance_m)
            ctx["predicted_force_n"] = force
            ctx["lever_arms_m"] = None
            return force
        prediction = self.estimator.predict_link(ctx["angles"])
        if prediction is None:
            raise InterlockTripped("link validation needs joint estimates, and none are available")
        ctx["prediction"] = prediction
        ctx["predicted_force_n"] = prediction["slip_force_n"]
        ctx["lever_arms_m"] = prediction["lever_arms_m"]
        return prediction["slip_force_n"]

    def _ramp_until_slip(self, trial: TrialPlan, ctx: dict[str, Any]) -> None:
        ramp = self.protocol.ramp
        winch = self.session.winch_id
        servos = self.session.servos
        predicted = self._predicted_force_n(trial, ctx)
        switch_n = self.detector_params.arm_threshold_n
        if predicted is not None and math.isfinite(predicted):
            switch_n = max(switch_n, ramp.fast_until_fraction * predicted)
        zero = self.winch_zero_rad
        assert zero is not None
        target = zero + self.config.limits.max_winch_travel_rev * 2 * math.pi
        radius = self.config.spool_radius_m
        # Timeout from the motion: the slow ramp to the protocol's maximum force, with the
        # nominal line stiffness, three times over, plus the margin.
        slow_s = ramp.max_force_n / (self.stiffness_n_per_m * radius * ramp.slow_speed_rad_s)
        timeout_s = 3.0 * slow_s + self.protocol.step_timeout_margin_s
        deadline = self.clock.monotonic_ns() + round(timeout_s * 1e9)

        fast = self.force_n < switch_n
        # The detector sees exactly the samples received from this instant on, which is also the
        # log time of the phase change, so `rig replay` can feed it the very same samples.
        ramp_start_ns = self.clock.time_ns()
        self._phase(
            Phase.RAMP_FAST if fast else Phase.RAMP_SLOW, trial.trial_id, "ramp_until_slip", ramp_start_ns
        )
        servos.set_profile(winch, velocity_rad_s=ramp.fast_speed_rad_s if fast else ramp.slow_speed_rad_s)
        servos.write_goal_positions({winch: target})
        self._command(winch, "goal_position", target, "rad")
        params = self.detector_params
        state = detector_init(params)
        event: SlipEvent | None = None
        peak_n = 0.0
        while event is None:
            self._tick()
            for t_ns, force in self.tick_samples:
                if t_ns < ramp_start_ns:
                    continue
                peak_n = max(peak_n, force)
                state, fired = detector_step(params, state, t_ns, force)
                if fired is not None:
                    if self._confirmed_by_winch(fired):
                        event = fired
                        break
                    state = detector_init(params)  # not a slip: start over, so a real one is seen
            if event is not None:
                break
            if fast and self.force_n >= switch_n:
                fast = False
                servos.set_profile(winch, velocity_rad_s=ramp.slow_speed_rad_s)
                servos.write_goal_positions({winch: target})
                self._command(winch, "goal_position", target, "rad")
                self._phase(Phase.RAMP_SLOW, trial.trial_id, "ramp_until_slip")
            if self.force_n >= ramp.max_force_n:
                ctx["outcome"] = "no_slip"
                self._note(
                    LogLevel.WARNING, f"trial {trial.trial_id}: no slip up to {ramp.max_force_n:.1f} N"
                )
                break
            if self.states[winch].position_rad >= target - _POSITION_TOLERANCE_RAD:
                ctx["outcome"] = "no_slip"
                self._note(LogLevel.WARNING, f"trial {trial.trial_id}: winch travel exhausted without a slip")
                break
            if self.clock.monotonic_ns() > deadline:
                raise RigTimeoutError(
                    f"trial {trial.trial_id}: ramp_until_slip exceeded its timeout of {timeout_s:.1f} s"
                )
        # Stop reeling: hold where the winch is, keep logging the post-slip tension briefly.
        hold = self.states[winch].position_rad
        servos.write_goal_positions({winch: hold})
        self._command(winch, "goal_position", hold, "rad")
        ctx["peak_observed_n"] = peak_n
        if event is not None:
            ctx["outcome"] = "slip"
            ctx["event"] = event
            self._ticks_for(ramp.hold_after_slip_s)
            if self.session.configuration is not None:
                ctx["slipped_joint"] = self.session.configuration.measure().slipped_joint
            self._log_slip(trial, event, ctx["slipped_joint"])

    def _confirmed_by_winch(self, event: SlipEvent) -> bool:
        """A tension drop is a slip only if the winch was not backing off (it reels in or holds)."""
        winch = self.states.get(self.session.winch_id)
        if winch is None or winch.hardware_error:
            return False
        confirmed = winch.velocity_rad_s > -0.05
        if not confirmed:
            self._note(LogLevel.WARNING, f"drop at {event.peak_force_n:.2f} N ignored: winch was backing off")
        return confirmed

    def _unload(self, trial: TrialPlan) -> None:
        self._phase(Phase.UNLOADING, trial.trial_id, "unload")
        self._release_tension(timeout_extra_s=self.protocol.step_timeout_margin_s)

    def _release_tension(self, timeout_extra_s: float) -> None:
        winch = self.session.winch_id
        zero = self.winch_zero_rad
        if zero is None:
            return
        speed = self.protocol.ramp.unload_speed_rad_s
        self.session.servos.set_profile(winch, velocity_rad_s=speed)
        self.session.servos.write_goal_positions({winch: zero})
        self._command(winch, "goal_position", zero, "rad")
        travel = abs(self.states[winch].position_rad - zero)
        self._wait_until(
            lambda: (
                abs(self.states[winch].position_rad - zero) < _POSITION_TOLERANCE_RAD
                and self.force_n < _RELEASED_TENSION_N + abs(self.tare_n)
            ),
            travel / speed * 2.0 + timeout_extra_s,
            "unload",
        )

    # ------------------------------------------------------------------ safety

    def _make_safe(self) -> str | None:
        """Release the line, then torque off every servo, then close; returns an error text or None."""
        errors: list[str] = []

        def release() -> None:
            if not self.connected or self.winch_zero_rad is None:
                return
            try:
                winch_state = self.states.get(self.session.winch_id)
                if winch_state is not None and winch_state.hardware_error:
                    return  # torque already dropped by the fault: the line is slack
                self._phase_quiet(Phase.UNLOADING)
                self._release_tension_without_interlocks()
            except Exception as exc:  # keep going to torque off
                errors.append(f"release failed: {exc}")

        try:
            self.session.servos.shutdown(release)
        except Exception as exc:
            errors.append(f"torque off failed: {exc}")
        try:
            self.session.load_cell.close()
        except Exception as exc:
            errors.append(f"load cell close failed: {exc}")
        try:
            self.session.close()
        except Exception as exc:
            errors.append(f"session close failed: {exc}")
        if errors:
            self._note(LogLevel.ERROR, "; ".join(errors))
            return "; ".join(errors)
        self._note(LogLevel.INFO, "safe state: line released, torque off")
        return None

    def _release_tension_without_interlocks(self) -> None:
        """Back the winch off to zero tension, bounded, ignoring interlocks (they caused this)."""
        winch = self.session.winch_id
        zero = self.winch_zero_rad
        assert zero is not None
        servos = self.session.servos
        speed = self.protocol.ramp.unload_speed_rad_s
        servos.set_profile(winch, velocity_rad_s=speed)
        servos.write_goal_positions({winch: zero})
        self._command(winch, "goal_position", zero, "rad")
        state = servos.read_states()[winch]
        deadline = self.clock.monotonic_ns() + round((abs(state.position_rad - zero) / speed * 2 + 2.0) * 1e9)
        while self.clock.monotonic_ns() < deadline:
            self.clock.sleep(self.protocol.control_period_s)
            self.states = servos.read_states()
            try:
                self._ingest(self.session.load_cell.poll())
            except StaleDataError:
                self.tick_samples = []
            if abs(self.states[winch].position_rad - zero) < _POSITION_TOLERANCE_RAD:
                return
        raise RigTimeoutError("winch did not return to zero tension within its timeout")

    # ------------------------------------------------------------------ results and logging

    def _result(self, trial: TrialPlan, ctx: dict[str, Any], start_ns: int) -> dict[str, Any]:
        event: SlipEvent | None = ctx.get("event")
        g = self.config.article.g
        peak = event.peak_force_n if event is not None else ctx.get("peak_observed_n")
        predicted_force = ctx.get("predicted_force_n")
        predicted_mass = predicted_force / g if predicted_force is not None else None
        slip_mass = peak / g if peak is not None else None
        pct = None
        if event is not None and predicted_mass is not None and trial.kind == "link_validation":
            pct = (predicted_mass - slip_mass) / slip_mass * 100.0
        angles = ctx.get("angles")
        return {
            "trial_id": trial.trial_id,
            "kind": trial.kind,
            "repeat": trial.repeat,
            "joint": trial.joint,
            "distance_m": trial.distance_m,
            "configuration_index": trial.configuration_index,
            "joint_angles_rad": list(angles) if angles is not None else None,
            "start_time_ns": start_ns,
            "end_time_ns": self.clock.time_ns(),
            "outcome": ctx.get("outcome", "no_slip"),
            "peak_force_n": peak,
            "slip_mass_kg": slip_mass,
            "predicted_force_n": predicted_force,
            "predicted_mass_kg": predicted_mass,
            "percentage_error": pct,
            "slipped_joint": ctx.get("slipped_joint"),
            "lever_arms_m": ctx.get("lever_arms_m"),
            "tare_n": self.tare_n,
        }

    def _result_payload(self, r: dict[str, Any]) -> dict[str, Any]:
        config = {"joint_angles_rad": r["joint_angles_rad"]} if r["joint_angles_rad"] is not None else None
        return schemas.trial_result(
            trial_id=r["trial_id"],
            kind=r["kind"],
            start_time_ns=r["start_time_ns"],
            end_time_ns=r["end_time_ns"],
            outcome=r["outcome"],
            peak_force_n=r["peak_force_n"],
            slip_mass_kg=r["slip_mass_kg"],
            predicted_mass_kg=r["predicted_mass_kg"],
            distance_m=r["distance_m"],
            configuration=config,
            slipped_joint=r["slipped_joint"],
            repeat=r["repeat"],
            lever_arms_m=r["lever_arms_m"],
        )

    def _estimate_payload(self, trial_id: int) -> dict[str, Any]:
        message = self.estimator.estimate_message(trial_id)
        fit = {k: v for k, v in message.items() if k not in ("trial_id", "joints")}
        return schemas.estimate(
            trial_id=trial_id, fit=fit if fit.get("n") else None, joints=message["joints"]
        )

    def _log_slip(self, trial: TrialPlan, event: SlipEvent, joint: int | None) -> None:
        self.log.log(
            schemas.SLIP,
            event.detection_time_ns,
            schemas.slip_event(
                trial_id=trial.trial_id,
                onset_time_ns=event.onset_time_ns,
                detection_time_ns=event.detection_time_ns,
                peak_time_ns=event.peak_time_ns,
                peak_force_n=event.peak_force_n,
                force_after_n=event.force_after_n,
                drop_fraction=event.drop_fraction,
                detector=self.detector_params.to_mapping(),
                trigger=event.trigger,
                joint=joint,
            ),
        )

    def _command(self, servo_id: int, command: str, value: float | None, unit: str) -> None:
        role = self.session.roles.get(servo_id, "")
        self.log.log(
            schemas.SERVO_COMMAND,
            self.clock.time_ns(),
            schemas.servo_command(servo_id=servo_id, role=role, command=command, value=value, unit=unit),
        )

    def _phase(
        self, phase: Phase, trial_id: int | None, step: str | None = None, at_ns: int | None = None
    ) -> None:
        if self.phases.to(phase):
            self.log.log(
                schemas.TRIAL_STATE,
                self.clock.time_ns() if at_ns is None else at_ns,
                schemas.trial_state(trial_id=trial_id, phase=phase, step=step),
            )

    def _phase_quiet(self, phase: Phase) -> None:
        """Best-effort phase change during cleanup (never raises)."""
        with contextlib.suppress(RuntimeError):
            self._phase(phase, self.trial.trial_id if self.trial else None, "safe_state")

    def _note(self, level: LogLevel, text: str) -> None:
        # The log itself may be what failed; the progress line below still tells.
        with contextlib.suppress(Exception):
            self.log.log(
                schemas.LOG,
                self.clock.time_ns(),
                schemas.log_message(time_ns=self.clock.time_ns(), level=level, message=text),
            )
        if level >= LogLevel.WARNING:
            self.progress.message(text)

    @staticmethod
    def _describe(trial: TrialPlan) -> str:
        if trial.kind == "joint_estimation":
            return f"joint {trial.joint} at {trial.distance_m:.3f} m (repeat {trial.repeat})"
        return f"configuration {trial.configuration_index} (repeat {trial.repeat})"


def percentage_error_summary(results: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Table IV statistics over the link-validation slips of a run, or None if there are none."""
    rows = [
        r
        for r in results
        if r["kind"] == "link_validation" and r["outcome"] == "slip" and r["predicted_mass_kg"]
    ]
    if not rows:
        return None
    stats = payload_error_stats([r["predicted_mass_kg"] for r in rows], [r["slip_mass_kg"] for r in rows])
    return stats.to_dict()
