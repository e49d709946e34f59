"""Limit checks before anything moves, and the `--dry-run` plan with its estimated duration.

`check_limits` raises `InputError` (exit 2, nothing started) when a protocol asks for more than
the rig allows. `plan_summary` describes what a run would do: trials, the checks and their
numbers, and an estimated duration from the ramp speeds, the nominal line stiffness and the load
cell's nominal rate (the ramp's rate cap, `rig.runner.ramp_speed`, one definition with the run's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, assert_never

from rig.errors import InputError
from rig.hw.bending import unreached_warning
from rig.inputs.protocol import AdaptiveBlock, Protocol, TrialPlan
from rig.inputs.rig_config import (
    MIN_STALE_SAMPLE_PERIODS,
    RigConfig,
    StaleTimeoutFit,
    nominal_loadcell_rate_hz,
)
from rig.runner.ramp_speed import RampSpeeds
from rig.vocabulary import RigKind, StepKind, TrialKind


@dataclass(frozen=True)
class LimitCheck:
    """One check: what, the value, the limit, and whether it passed."""

    name: str
    value: str
    limit: str
    ok: bool
    of_rig_alone: bool = False  # the rig config's own values: its file is named first when it fails


# The direction check must expect a rise of this many zero tolerances at the nominal stiffness, so
# that a line softer than its nominal stiffness still rises past one before the check ends.
DIRECTION_CHECK_MARGIN = 1.5


def direction_check_rise_n(config: RigConfig) -> float:
    """The tension rise over the ramp's direction check (`limits.direction_check_rev`), nominal stiffness."""
    travel_rad = config.limits.direction_check_rev * 2 * math.pi
    return config.line_n_per_rad * travel_rad


def limit_checks(protocol: Protocol, config: RigConfig) -> list[LimitCheck]:
    """Every check, passed or not."""
    limits = config.limits
    ceiling = limits.force_ceiling_n
    checks = []
    if protocol.force_ceiling_n is not None:
        checks.append(
            LimitCheck(
                "protocol force ceiling <= rig force ceiling",
                f"{protocol.force_ceiling_n:.1f} N",
                f"{ceiling:.1f} N",
                protocol.force_ceiling_n <= ceiling,
            )
        )
        ceiling = min(ceiling, protocol.force_ceiling_n)
    ramp = protocol.ramp
    checks.append(
        LimitCheck(
            "ramp max force < force ceiling",
            f"{ramp.max_force_n:.1f} N",
            f"{ceiling:.1f} N",
            ramp.max_force_n < ceiling,
        )
    )
    stall_force = config.winch_stall_tension_n
    checks.append(
        LimitCheck(
            "winch stall tension (current limit) >= ramp max force",
            f"{stall_force:.1f} N",
            f"{ramp.max_force_n:.1f} N",
            stall_force >= ramp.max_force_n,
        )
    )
    travel_rev = ramp.max_force_n / config.line_n_per_rad / (2 * math.pi)
    checks.append(
        LimitCheck(
            "winch travel to reach max force (nominal stiffness) <= travel limit",
            f"{travel_rev:.2f} rev",
            f"{limits.max_winch_travel_rev:.2f} rev",
            travel_rev <= limits.max_winch_travel_rev,
        )
    )
    checks.append(
        LimitCheck(
            "ramp hold after a slip < time loaded after a slip",
            f"{ramp.hold_after_slip_s:g} s",
            f"{limits.max_loaded_after_slip_s:g} s",
            ramp.hold_after_slip_s < limits.max_loaded_after_slip_s,
        )
    )
    direction_rise_n = direction_check_rise_n(config)
    checks.append(
        LimitCheck(
            "tension rise over the direction check (nominal stiffness) >= 1.5 x zero tolerance",
            f"{direction_rise_n:.2f} N over {limits.direction_check_rev:g} rev",
            f"{DIRECTION_CHECK_MARGIN * limits.zero_tolerance_n:.2f} N",
            direction_rise_n >= DIRECTION_CHECK_MARGIN * limits.zero_tolerance_n,
            of_rig_alone=True,
        )
    )
    rate_hz = config.loadcell.rate_hz
    if rate_hz is not None:  # a hardware cell of unstated rate is measured by `rig check` only
        fit = StaleTimeoutFit(limits.stale_timeout_s, rate_hz)
        checks.append(
            LimitCheck(
                f"stale timeout >= {MIN_STALE_SAMPLE_PERIODS} sample periods at loadcell.rate_hz {rate_hz:g}",
                f"limits.stale_timeout_s {limits.stale_timeout_s:g} s ({fit.periods:.1f} periods)",
                f"{fit.least_s:.3g} s",
                fit.ok,
                of_rig_alone=True,
            )
        )
    for trial in protocol.trials:
        if trial.joint is not None and trial.joint > config.article.joint_count:
            checks.append(
                LimitCheck(
                    f"trial {trial.trial_id}: joint exists",
                    str(trial.joint),
                    str(config.article.joint_count),
                    False,
                )
            )
    for block in protocol.adaptive:
        if block.joint > config.article.joint_count:
            checks.append(
                LimitCheck(
                    f"block {block.block} (adaptive): joint exists",
                    str(block.joint),
                    str(config.article.joint_count),
                    False,
                )
            )
    return checks


def check_limits(protocol: Protocol, config: RigConfig) -> list[LimitCheck]:
    """Raise InputError naming the first failed check; return all checks when they pass."""
    checks = limit_checks(protocol, config)
    failed = [c for c in checks if not c.ok]
    if failed:
        c = failed[0]
        if c.of_rig_alone:
            raise InputError(f"{config.source}: limit check failed: {c.name}: {c.value} vs limit {c.limit}")
        raise InputError(
            f"{protocol.source}: limit check failed: {c.name}: {c.value} vs limit {c.limit} "
            f"(rig {config.source})"
        )
    return checks


def ramp_speeds(protocol: Protocol, config: RigConfig) -> RampSpeeds:
    """The ramp's speeds on this rig at its load cell's nominal rate (as `ramp_until_slip` has them)."""
    ramp = protocol.ramp
    return RampSpeeds(
        fast_rad_s=ramp.fast_speed_rad_s,
        slow_rad_s=ramp.slow_speed_rad_s,
        rate_hz=nominal_loadcell_rate_hz(config),
        n_per_rad=config.line_n_per_rad,
    )


def loaded_after_slip_s(protocol: Protocol, config: RigConfig, slip_force_n: float) -> float:
    """How long a slip at `slip_force_n` keeps the line loaded: the hold, then the unload's travel.

    At the nominal line stiffness, the tension falling as fast as the winch pays out at
    `ramp.unload_speed_rad_s` (docs/design.md §6 2e).
    """
    ramp = protocol.ramp
    return ramp.hold_after_slip_s + slip_force_n / (config.line_n_per_rad * ramp.unload_speed_rad_s)


def loaded_after_slip_warning(protocol: Protocol, config: RigConfig, slip_force_n: float) -> str | None:
    """A warning when a slip at `slip_force_n` would keep the line loaded beyond the rig's bound."""
    loaded_s = loaded_after_slip_s(protocol, config, slip_force_n)
    bound_s = config.limits.max_loaded_after_slip_s
    if loaded_s <= bound_s:
        return None
    ramp = protocol.ramp
    return (
        f"a slip at {slip_force_n:.1f} N would keep the line loaded about {loaded_s:.1f} s "
        f"(ramp.hold_after_slip_s {ramp.hold_after_slip_s:g} s, then {slip_force_n:.1f} N paid out at "
        f"ramp.unload_speed_rad_s {ramp.unload_speed_rad_s:g} rad/s on a line of nominal stiffness "
        f"{config.line_stiffness_n_per_m:g} N/m), "
        f"beyond limits.max_loaded_after_slip_s ({bound_s:g} s): raise ramp.unload_speed_rad_s within the "
        "winch's speed, or keep clear of the link until the line is slack (the run logs each slip's time)"
    )


def estimated_trial_s(
    trial: TrialPlan, protocol: Protocol, config: RigConfig, typical_force_n: float, *, first: bool = False
) -> float:
    """Rough duration of one trial: tare, ramps, unload, pauses, bending (no operator time).

    The ramp to `typical_force_n` is timed as `ramp_until_slip` runs it at the load cell's nominal
    rate (`RampSpeeds.planned_ramp_s`: slower at low rates; the `first` trial has nothing to go on).
    """
    ramp = protocol.ramp
    speeds = ramp_speeds(protocol, config)
    seconds = speeds.planned_ramp_s(
        protocol.detector.arm_threshold_n,
        typical_force_n,
        first,
        ramp.fast_until_fraction,
        protocol.control_period_s,
    )
    seconds += loaded_after_slip_s(protocol, config, typical_force_n)
    for step in trial.steps:
        match step.kind:
            case StepKind.PAUSE | StepKind.TARE:
                seconds += step.duration_s
            case StepKind.BEND | StepKind.RESET:
                seconds += 1.0
            case StepKind.PROMPT | StepKind.MEASURE | StepKind.UNLOAD | StepKind.RAMP_UNTIL_SLIP:
                pass  # operator time is not counted; the unload and the ramp are counted above
            case kind:
                assert_never(kind)
    return seconds


def max_slip_force_n(block: AdaptiveBlock, protocol: Protocol, config: RigConfig) -> float:
    """The highest slip force an adaptive block may aim at: a share of the ramp's maximum and the ceiling."""
    ceiling = config.limits.force_ceiling_n
    if protocol.force_ceiling_n is not None:
        ceiling = min(ceiling, protocol.force_ceiling_n)
    return block.max_force_fraction * min(protocol.ramp.max_force_n, ceiling)


def startup_trials(block: AdaptiveBlock) -> list[TrialPlan]:
    """An adaptive block's start-up trials as planned (before the force filter moves any of them)."""
    distances = block.design.startup_m
    return [
        block.trial(block.first_trial_id + i, d, 1 + distances[:i].count(d)) for i, d in enumerate(distances)
    ]


@dataclass(frozen=True)
class PlannedTrial:
    """One trial as the dry run shows it."""

    trial_id: int
    kind: TrialKind
    repeat: int
    joint: int | None
    distance_m: float | None
    configuration_index: int | None
    joint_angles_deg: tuple[float, ...] | None  # rounded to 0.001°
    steps: tuple[StepKind, ...]

    @classmethod
    def of(cls, trial: TrialPlan) -> PlannedTrial:
        """The dry run's view of a planned trial."""
        angles = trial.joint_angles_rad
        return cls(
            trial_id=trial.trial_id,
            kind=trial.kind,
            repeat=trial.repeat,
            joint=trial.joint,
            distance_m=trial.distance_m,
            configuration_index=trial.configuration_index,
            joint_angles_deg=tuple(round(math.degrees(a), 3) for a in angles) if angles else None,
            steps=tuple(s.kind for s in trial.steps),
        )

    def as_json(self) -> dict[str, Any]:
        """The `rig run --dry-run --json` entry of `trials`."""
        return {
            "trial_id": self.trial_id,
            "kind": self.kind,
            "repeat": self.repeat,
            "joint": self.joint,
            "distance_m": self.distance_m,
            "configuration_index": self.configuration_index,
            "joint_angles_deg": None if self.joint_angles_deg is None else list(self.joint_angles_deg),
            "steps": list(self.steps),
        }


@dataclass(frozen=True)
class AdaptivePlan:
    """What a dry run can say of an adaptive block before any trial."""

    block: int
    joint: int
    first_trial_id: int
    startup_trials: int
    min_trials: int
    max_trials: int
    distance_range_m: tuple[float, float]
    candidate_distances_m: tuple[float, ...]
    target_half_width_rel: float
    estimator: str
    max_slip_force_n: float
    text: str  # how the block goes on after its start-up trials, for the operator

    def as_json(self) -> dict[str, Any]:
        """The `rig run --dry-run --json` entry of `adaptive`."""
        return {
            "block": self.block,
            "joint": self.joint,
            "first_trial_id": self.first_trial_id,
            "startup_trials": self.startup_trials,
            "min_trials": self.min_trials,
            "max_trials": self.max_trials,
            "distance_range_m": list(self.distance_range_m),
            "candidate_distances_m": list(self.candidate_distances_m),
            "target_half_width_rel": self.target_half_width_rel,
            "estimator": self.estimator,
            "max_slip_force_n": self.max_slip_force_n,
            "text": self.text,
        }


@dataclass(frozen=True)
class PlanSummary:
    """The dry run's description of a run: trials, limit checks, estimated duration."""

    protocol: str
    rig: str
    rig_kind: RigKind
    trials: tuple[PlannedTrial, ...]  # an adaptive block's start-up trials among them
    limit_checks: tuple[LimitCheck, ...]
    estimated_duration_s: float
    duration_assumption: str
    adaptive: tuple[AdaptivePlan, ...] = ()
    # One winch count's tension: the finest the slip load can be read (rig.runner.ramp_speed).
    slip_load_resolution_n: float = 0.0
    # Configurations that bend joints no fork reaches (`rig.hw.bending.unreached_warning`), a long
    # loaded time after a slip, joint-estimation blocks that move the hook without a prompt.
    warnings: tuple[str, ...] = ()

    def as_json(self) -> dict[str, Any]:
        """The `rig run --dry-run --json` object (`adaptive` only when the protocol has such blocks)."""
        out: dict[str, Any] = {
            "protocol": self.protocol,
            "rig": self.rig,
            "rig_kind": self.rig_kind,
            "trials": [t.as_json() for t in self.trials],
            "limit_checks": [
                {"check": c.name, "value": c.value, "limit": c.limit, "ok": c.ok} for c in self.limit_checks
            ],
            "estimated_duration_s": self.estimated_duration_s,
            "duration_assumption": self.duration_assumption,
            "slip_load_resolution_n": self.slip_load_resolution_n,
        }
        if self.adaptive:
            out["adaptive"] = [a.as_json() for a in self.adaptive]
        if self.warnings:
            out["warnings"] = list(self.warnings)
        return out


def plan_summary(protocol: Protocol, config: RigConfig) -> PlanSummary:
    """The dry-run description: trials, checks and estimated duration.

    For an adaptive block the trials listed are its start-up trials, and `adaptive` says how it goes
    on; its duration counts its whole budget.
    """
    checks = limit_checks(protocol, config)
    typical = 0.5 * protocol.ramp.max_force_n
    shown: list[TrialPlan] = []
    for item in protocol.schedule:
        shown += startup_trials(item) if isinstance(item, AdaptiveBlock) else [item]
    durations = [
        estimated_trial_s(t, protocol, config, typical, first=i == 0) for i, t in enumerate(protocol.trials)
    ]
    for block in protocol.adaptive:
        sample = block.trial(block.first_trial_id, block.design.distance_max_m, 1)
        durations.append(block.design.max_trials * estimated_trial_s(sample, protocol, config, typical))
    return PlanSummary(
        protocol=protocol.name,
        rig=config.name,
        rig_kind=config.kind,
        trials=tuple(PlannedTrial.of(t) for t in shown),
        limit_checks=tuple(checks),
        estimated_duration_s=sum(durations),
        duration_assumption=(
            f"slip at {typical:.1f} N in every trial, nominal line stiffness "
            f"{config.line_stiffness_n_per_m:g} N/m, the ramp at the load cell's "
            f"{nominal_loadcell_rate_hz(config):g} samples/s, no operator time"
            + (", every adaptive block's whole budget" if protocol.adaptive else "")
        ),
        adaptive=tuple(adaptive_plan(block, protocol, config) for block in protocol.adaptive),
        slip_load_resolution_n=ramp_speeds(protocol, config).count_n,
        warnings=tuple(
            w
            for w in (
                loaded_after_slip_warning(protocol, config, typical),
                *fork_warnings(protocol, config),
                *hook_warnings(protocol),
            )
            if w
        ),
    )


def hook_warnings(protocol: Protocol) -> tuple[str, ...]:
    """One warning per joint-estimation block whose trials move the hook without a prompt.

    The rig cannot move the hook: only a person asked by a `prompt` step does, so without one every
    trial of the block runs wherever the hook hangs (a real rig's behaviour, and the simulated one's).
    An adaptive block's planner moves it from trial to trial.
    """
    places: dict[int, set[tuple[int | None, float | None]]] = {}
    for trial in protocol.trials:
        if trial.kind is TrialKind.JOINT_ESTIMATION and not _prompts(trial):
            places.setdefault(trial.block, set()).add((trial.joint, trial.distance_m))
    moving = {block for block, where in places.items() if len(where) > 1}
    for adaptive in protocol.adaptive:
        sample = adaptive.trial(adaptive.first_trial_id, adaptive.design.distance_max_m, 1)
        if not _prompts(sample):
            moving.add(sample.block)
    return tuple(
        f"block {block + 1} (joint_estimation): its trials hang the load at different places but its "
        "steps have no prompt, so nobody is asked to move the hook and every trial runs where it hangs "
        "(add `prompt` to the block's steps)"
        for block in sorted(moving)
    )


def _prompts(trial: TrialPlan) -> bool:
    return any(step.kind == StepKind.PROMPT for step in trial.steps)


def fork_warnings(protocol: Protocol, config: RigConfig) -> tuple[str, ...]:
    """One warning per configuration of the protocol that bends a joint no fork of the rig reaches."""
    out: dict[int | None, str] = {}
    for trial in protocol.trials:
        if trial.joint_angles_rad is None or trial.configuration_index in out:
            continue
        bends = any(s.kind == StepKind.BEND for s in trial.steps)
        text = unreached_warning(
            config, trial.configuration_index, trial.joint_angles_rad, trial.bend_tolerance_rad
        )
        if bends and text is not None:
            out[trial.configuration_index] = text
    return tuple(out.values())


def adaptive_plan(block: AdaptiveBlock, protocol: Protocol, config: RigConfig) -> AdaptivePlan:
    """What a dry run can say of an adaptive block before any trial."""
    design = block.design
    limit_n = max_slip_force_n(block, protocol, config)
    return AdaptivePlan(
        block=block.block,
        joint=block.joint,
        first_trial_id=block.first_trial_id,
        startup_trials=design.startup_trials,
        min_trials=design.min_trials,
        max_trials=design.max_trials,
        distance_range_m=(design.distance_min_m, design.distance_max_m),
        candidate_distances_m=tuple(design.candidates_m),
        target_half_width_rel=design.target_half_width_rel,
        estimator=design.estimator,
        max_slip_force_n=limit_n,
        text=(
            f"then adaptive up to {design.max_trials} trials in all: the distance that most narrows the "
            f"bound on k ({design.estimator}) among {design.distance_count} from {design.distance_min_m:g} "
            f"to {design.distance_max_m:g} m whose predicted slip force stays below "
            f"{limit_n:.1f} N; stops once the half-width is at most "
            f"{100 * design.target_half_width_rel:g} % of k (after at least {design.min_trials} trials)"
        ),
    )
