"""The steps a trial is made of, one function each, and the table that maps a step kind to its function.

A trial runs its protocol template (`TrialPlan.steps`) in order through `STEPS`; every step gets
the run's parts (`StepContext`), its own options (`StepSpec`), the trial and what the trial has
measured so far. `STEPS` is built through a `match` over `StepKind`, so mypy names this module
when a step kind is added.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import assert_never

from rig.errors import InterlockTripped, StaleDataError
from rig.hw.bending import BendStage, fork_components, unreached_warning
from rig.hw.session import OperatorRequest, OperatorTask
from rig.inputs.protocol import StepSpec, TrialPlan
from rig.records import LogLevel, ServoCommandName, TrialPhase
from rig.runner.measuring import measure_configuration
from rig.runner.ramp import ramp_until_slip
from rig.runner.results import TrialMeasurements
from rig.runner.step_context import BENDER_SPEED_RAD_S, StepContext
from rig.runner.unloading import release_before_waiting, unload_line
from rig.safety.safe_state import POSITION_TOLERANCE_RAD, move_timeout_s
from rig.vocabulary import ServoRole, StepKind

StepUnit = Callable[[StepContext, StepSpec, TrialPlan, TrialMeasurements], None]


def prompt(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Ask the operator to do what the prompt says (the loop ticks while waiting)."""
    release_before_waiting(ctx, trial)
    ctx.recorder.phase(TrialPhase.PROMPTING, trial.trial_id, StepKind.PROMPT)
    request = OperatorRequest(OperatorTask.FOLLOW_PROMPT, trial.prompt_text(step.text or ""), trial)
    ctx.session.operator.confirm(request, ctx.loop.tick)


def tare(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Average the load cell over `duration_s`: the force the later readings are taken relative to."""
    loop = ctx.loop
    settle_s = step.duration_s
    ctx.recorder.phase(TrialPhase.TARING, trial.trial_id, StepKind.TARE)
    loop.tare_n = 0.0
    raw_forces: list[float] = []
    end = loop.clock.monotonic_ns() + round(settle_s * 1e9)
    while loop.clock.monotonic_ns() < end:
        loop.tick()
        raw_forces += [s.force_n for s in loop.tick_samples]
    if not raw_forces:
        raise StaleDataError(f"no load-cell samples during the {settle_s:.2f} s tare window")
    tare_n = sum(raw_forces) / len(raw_forces)
    tolerance_n = ctx.config.limits.zero_tolerance_n
    if abs(tare_n) > tolerance_n:  # an interlock, not a correction: the line is not slack at zero
        raise InterlockTripped(
            f"trial {trial.trial_id}: tare {tare_n:+.2f} N beyond limits.zero_tolerance_n "
            f"({tolerance_n:g} N): the line is not slack at the winch's zero, or the load cell's zero "
            "moved; slacken the line, check the cell, then resume the run"
        )
    loop.tare_n = tare_n
    ctx.recorder.note(
        LogLevel.INFO, f"trial {trial.trial_id}: tare {loop.tare_n:+.4f} N over {len(raw_forces)} samples"
    )


def bend(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Bend the link to the trial's configuration: by the forks, base to tip, or by the operator's hands."""
    ctx.recorder.phase(TrialPhase.BENDING, trial.trial_id, StepKind.BEND)
    angles = trial.joint_angles_rad or ()
    fixture = ctx.session.fixture
    straight = (0.0,) * len(angles)  # a bend starts from the reset (straight) link
    unreached = unreached_warning(ctx.config, trial.configuration_index, angles, trial.bend_tolerance_rad)
    if unreached is not None:  # before anything moves, so that the operator can stop the run
        ctx.recorder.note(LogLevel.WARNING, f"trial {trial.trial_id}: {unreached}")
    stages = fixture.bend_stages(angles, straight, _positions(ctx))
    if not stages and not fork_components(ctx.config):
        degrees = ", ".join(f"{math.degrees(a):.1f}" for a in angles)
        text = f"Bend the link to configuration {trial.configuration_index}: [{degrees}] deg"
        _by_hand(ctx, trial, OperatorRequest(OperatorTask.BEND_LINK, text, trial, tuple(angles)))
        return
    _run_stages(ctx, stages)
    if StepKind.MEASURE not in [s.kind for s in trial.steps]:
        fixture.end_bend()  # nothing will correct it: the forks open now


def measure(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Measure the link's configuration and, with forks, correct it toward the target (bounded).

    Every measurement is logged on `/rig/configuration/measured` beside the commanded angles; the
    prediction uses the last one. Without a source the commanded angles stand in.
    """
    source = ctx.session.configuration
    fixture = ctx.session.fixture
    if source is None:
        fixture.end_bend()
        return
    target = trial.joint_angles_rad
    release_before_waiting(ctx, trial)  # the source may be a person or a camera
    reading = measure_configuration(ctx, trial, after_slip=False, attempt=0)
    attempt = 0
    while target is not None and reading.joint_angles_rad is not None and attempt < trial.bend_corrections:
        if _worst_error_rad(reading.joint_angles_rad, target) <= trial.bend_tolerance_rad:
            break
        stages = fixture.bend_stages(
            target,
            reading.joint_angles_rad,
            _positions(ctx),
            tolerance_rad=trial.bend_tolerance_rad,
            correcting=True,
        )
        if not stages:
            break
        attempt += 1
        _run_stages(ctx, stages)
        reading = measure_configuration(ctx, trial, after_slip=False, attempt=attempt)
    fixture.end_bend()
    if reading.joint_angles_rad is not None:
        found.joint_angles_rad = tuple(reading.joint_angles_rad)
        if target is not None and attempt > 0:
            worst = _worst_error_rad(reading.joint_angles_rad, target)
            level = LogLevel.INFO if worst <= trial.bend_tolerance_rad else LogLevel.WARNING
            ctx.recorder.note(
                level,
                f"trial {trial.trial_id}: configuration {trial.configuration_index} reached within "
                f"{math.degrees(worst):.2f} deg after {attempt} corrections (tolerance "
                f"{math.degrees(trial.bend_tolerance_rad):.2f} deg); the prediction uses the measurement",
            )
    found.measured = reading


def _worst_error_rad(measured: Sequence[float], target: Sequence[float]) -> float:
    return max((abs(m - t) for m, t in zip(measured, target, strict=True)), default=0.0)


def _positions(ctx: StepContext) -> dict[int, float]:
    """Every bender's present shaft angle [rad]."""
    return {
        sid: ctx.loop.states[sid].position_rad
        for sid, role in ctx.session.roles.items()
        if role == ServoRole.BENDER and sid in ctx.loop.states
    }


def _run_stages(ctx: StepContext, stages: Sequence[BendStage]) -> None:
    """Move the forks one at a time, each closing on its component first and holding once there."""
    fixture = ctx.session.fixture
    for stage in stages:
        fixture.begin_stage(stage)
        _move_servos(ctx, {stage.servo_id: stage.goal_rad}, StepKind.BEND, speed_rad_s=BENDER_SPEED_RAD_S)
        fixture.end_stage(stage)


def ramp(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Load the line until the joint slips (`rig.runner.ramp`)."""
    ramp_until_slip(ctx, trial, found)


def unload(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Back the winch off to its zero-tension angle with the interlocks live (`rig.runner.unloading`).

    After a slip the ramp has released the line already, before anything slow: nothing is left to do.
    """
    if found.line_released:
        return
    unload_line(ctx, trial)


def reset(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Straighten the link: by the fixture's servos, or by the operator."""
    ctx.recorder.phase(TrialPhase.RESETTING, trial.trial_id, StepKind.RESET)
    goals = ctx.session.fixture.home_goals()
    if not goals:
        text = "Straighten the link (reset), then confirm."
        _by_hand(ctx, trial, OperatorRequest(OperatorTask.STRAIGHTEN_LINK, text, trial))
        return
    _move_servos(ctx, goals, StepKind.RESET, speed_rad_s=BENDER_SPEED_RAD_S)


def pause(ctx: StepContext, step: StepSpec, trial: TrialPlan, found: TrialMeasurements) -> None:
    """Wait `duration_s`, ticking."""
    ctx.recorder.phase(TrialPhase.PAUSING, trial.trial_id, StepKind.PAUSE)
    ctx.loop.ticks_for(step.duration_s)


def _by_hand(ctx: StepContext, trial: TrialPlan, request: OperatorRequest) -> None:
    """The operator sets the link by hand: the benders' torque is off meanwhile, so that they give way.

    Afterwards each bender holds where the operator left it (its goal set to its position before
    its torque comes back on), so the configuration stays as bent.
    """
    release_before_waiting(ctx, trial)
    benders = [sid for sid, role in ctx.session.roles.items() if role == ServoRole.BENDER]
    servos = ctx.session.servos
    if benders:
        servos.set_torque(benders, False)
        for sid in benders:
            ctx.recorder.command(sid, ServoCommandName.TORQUE, 0.0, "")
    ctx.session.operator.confirm(request, ctx.loop.tick)
    if benders:
        ctx.loop.tick()
        held = {sid: ctx.loop.states[sid].position_rad for sid in benders}
        servos.write_goal_positions(held)
        servos.set_torque(benders, True)
        for sid in benders:
            ctx.recorder.command(sid, ServoCommandName.GOAL_POSITION, held[sid], "rad")
            ctx.recorder.command(sid, ServoCommandName.TORQUE, 1.0, "")


def _move_servos(ctx: StepContext, goals: dict[int, float], what: str, speed_rad_s: float) -> None:
    """Send the servos to `goals` and wait until each has arrived and stopped."""
    if not goals:
        return
    loop = ctx.loop
    ctx.session.servos.write_goal_positions(goals)
    for sid, goal in goals.items():
        ctx.recorder.command(sid, ServoCommandName.GOAL_POSITION, goal, "rad")
    travel = max(abs(goal - loop.states[sid].position_rad) for sid, goal in goals.items())
    timeout = move_timeout_s(travel, speed_rad_s, ctx.protocol.step_timeout_margin_s)

    def arrived() -> bool:
        return all(
            abs(loop.states[sid].position_rad - goal) < POSITION_TOLERANCE_RAD and not loop.states[sid].moving
            for sid, goal in goals.items()
        )

    loop.wait_until(arrived, timeout, what)


def _unit(kind: StepKind) -> StepUnit:
    """The function of one step kind (mypy names this match when a kind is added)."""
    match kind:
        case StepKind.PROMPT:
            return prompt
        case StepKind.TARE:
            return tare
        case StepKind.BEND:
            return bend
        case StepKind.MEASURE:
            return measure
        case StepKind.RAMP_UNTIL_SLIP:
            return ramp
        case StepKind.UNLOAD:
            return unload
        case StepKind.RESET:
            return reset
        case StepKind.PAUSE:
            return pause
        case _:
            assert_never(kind)


STEPS: Mapping[StepKind, StepUnit] = MappingProxyType({kind: _unit(kind) for kind in StepKind})
