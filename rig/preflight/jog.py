"""Pre-flight section `move` (only with `rig check --move`): a small supervised jog of the winch.

It finds which way the winch reels line in (the tension rises) and measures the line's stiffness:

1. Only from a slack line (the load cell within `limits.zero_tolerance_n`), with the winch in
   current-based position mode at the rig's current limit, slowly (`JOG_SPEED_RAD_S`).
2. The winch turns the configured reel-in way (`reel_direction`) until the tension has risen by
   `jog_target_n` (5 N, or a tenth of the force ceiling if less), or for `jog_travel_rev` (1 rev by
   default, `rig check --jog-travel-rev`); then back
   to where it started. If the tension did not rise, the same the other way: a rise there means the
   drum is wound the other way (`reel_direction` must flip).
3. The stiffness is the slope of tension against line reeled in (drum angle x spool radius) over the
   taut part of the jog (from 30 % of the target), by least squares.

The winch always ends where it started with its torque off (the context's close turns it off after a
failure too). Not verified on hardware: the sequence runs on the simulated rig and the emulators.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

from rig.errors import InterlockTripped, RigError
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.seams import Clock, LoadCell, OperatingMode
from rig.preflight.check_context import CheckContext, JogFindings
from rig.preflight.verdicts import CheckRow, Verdict

SECTION = "move"
JOG_SPEED_RAD_S = 0.5
JOG_TARGET_N = 5.0
JOG_TICK_S = 0.02
RETURN_TOLERANCE_RAD = 0.02
TAUT_FRACTION = 0.3  # the stiffness fit starts at this share of the target rise
MIN_FIT_POINTS = 3
# The nominal stiffness in the config is fine within these factors of the measured one: the ramp's
# timeout allows a line 3 x softer than nominal; a nominal far below the truth only lengthens plans.
STIFFNESS_RATIO_OK = (1 / 3, 3.0)


@dataclass(frozen=True)
class JogTrace:
    """One jog one way: (line reeled in [m], tension rise [N]) per tick, and whether the target was met."""

    direction: int
    points: tuple[tuple[float, float], ...]
    reached: bool

    @property
    def rise_n(self) -> float:
        """The largest tension rise seen."""
        return max((f for _, f in self.points), default=0.0)


def jog_target_n(ceiling_n: float) -> float:
    """The tension rise the jog stops at: 5 N, or a tenth of the force ceiling if that is less."""
    return min(JOG_TARGET_N, 0.1 * ceiling_n)


def jog_rows(ctx: CheckContext) -> list[CheckRow]:
    """Jog the winch (only with `--move`); rows for the reel direction and the line stiffness."""
    if not ctx.options.move:
        return []
    config = ctx.config
    bus = ctx.servo_bus()
    cell = ctx.load_cell()
    if bus is None or cell is None:
        reason = ctx.servo_failure or ctx.cell_failure
        return [CheckRow(SECTION, "jog", Verdict.FAIL, f"not started: {reason}", "fix the sections above")]
    if not ctx.calibrated:
        return [CheckRow(SECTION, "jog", Verdict.FAIL, "not started: the load cell has no calibration", "")]
    samples = ctx.cell_samples() or []
    baseline_n = statistics.fmean(s.force_n for s in samples) if samples else math.nan
    if not abs(baseline_n) <= config.limits.zero_tolerance_n:
        fix = "slacken the line first (see the line section)"
        return [
            CheckRow(SECTION, "jog", Verdict.FAIL, f"not started: the line reads {baseline_n:+.2f} N", fix)
        ]
    winch = config.servos.winch.servo_id
    target_n = jog_target_n(config.limits.force_ceiling_n)
    try:
        traces = _jog_both_ways(ctx, bus, cell, winch, baseline_n, target_n)
    except RigError as exc:
        fix = "check the winch and the line by hand; the winch's torque is off"
        return [CheckRow(SECTION, "jog", Verdict.FAIL, f"stopped: {type(exc).__name__}: {exc}", fix)]
    findings = findings_of(traces, target_n)
    ctx.jog_findings = findings
    return [direction_row(ctx, traces, findings, target_n), stiffness_row(ctx, findings)]


def _jog_both_ways(
    ctx: CheckContext, bus: DynamixelServoBus, cell: LoadCell, winch: int, baseline_n: float, target_n: float
) -> list[JogTrace]:
    config = ctx.config
    limit_a = config.limits.winch_current_limit_a
    bus.set_current_limit(winch, limit_a)
    bus.set_operating_mode(
        winch,
        OperatingMode.CURRENT_BASED_POSITION,
        goal_current_a=limit_a,
        profile_velocity_rad_s=JOG_SPEED_RAD_S,
    )
    zero_rad = bus.read_states()[winch].position_rad
    bus.write_goal_positions({winch: zero_rad})  # no stale goal to jump to when the torque comes on
    bus.set_torque([winch], True)
    traces: list[JogTrace] = []
    try:
        for direction in (config.reel_direction, -config.reel_direction):
            trace = _reel(ctx, bus, cell, winch, zero_rad, direction, baseline_n, target_n)
            traces.append(trace)
            _move_to(ctx.clock, bus, winch, zero_rad)
            if trace.reached:
                break
    finally:
        bus.set_torque([winch], False)
    return traces


def _reel(
    ctx: CheckContext,
    bus: DynamixelServoBus,
    cell: LoadCell,
    winch: int,
    zero_rad: float,
    direction: int,
    baseline_n: float,
    target_n: float,
) -> JogTrace:
    """Turn `direction` until the tension has risen by `target_n` or the travel is spent."""
    clock = ctx.clock
    radius_m = ctx.config.spool_radius_m
    ceiling_n = ctx.config.limits.force_ceiling_n
    travel_rad = ctx.options.jog_travel_rev * 2 * math.pi
    goal_rad = zero_rad + direction * travel_rad
    bus.write_goal_positions({winch: goal_rad})
    deadline_ns = clock.monotonic_ns() + round((travel_rad / JOG_SPEED_RAD_S * 1.5 + 2.0) * 1e9)
    points: list[tuple[float, float]] = []
    cell.poll()  # start from fresh samples
    while clock.monotonic_ns() < deadline_ns:
        clock.sleep(JOG_TICK_S)
        state = bus.read_states()[winch]
        bus.raise_for_hardware_errors({winch: state})
        position_rad = state.position_rad
        samples = cell.poll()
        if not samples:
            continue
        if max(s.force_n for s in samples) > ceiling_n:  # a stiff line overshot the target: stop here
            bus.write_goal_positions({winch: position_rad})
            raise InterlockTripped(
                f"the tension passed limits.force_ceiling_n ({ceiling_n:g} N) during the jog"
            )
        rise_n = samples[-1].force_n - baseline_n
        points.append((direction * (position_rad - zero_rad) * radius_m, rise_n))
        if rise_n >= target_n:
            bus.write_goal_positions({winch: position_rad})  # hold here, then go back
            return JogTrace(direction, tuple(points), True)
        if abs(position_rad - goal_rad) < RETURN_TOLERANCE_RAD:
            break
    return JogTrace(direction, tuple(points), False)


def _move_to(clock: Clock, bus: DynamixelServoBus, winch: int, goal_rad: float) -> None:
    """Send the winch to `goal_rad` and wait until it is there (a RigError if it does not get there)."""
    bus.write_goal_positions({winch: goal_rad})
    position_rad = bus.read_states()[winch].position_rad
    deadline_ns = clock.monotonic_ns() + round(
        (abs(position_rad - goal_rad) / JOG_SPEED_RAD_S * 1.5 + 2.0) * 1e9
    )
    while abs(position_rad - goal_rad) >= RETURN_TOLERANCE_RAD:
        if clock.monotonic_ns() > deadline_ns:
            raise RigError(
                f"the winch did not return to where the jog started ({position_rad - goal_rad:+.2f} rad off)"
            )
        clock.sleep(JOG_TICK_S)
        position_rad = bus.read_states()[winch].position_rad


def findings_of(traces: list[JogTrace], target_n: float) -> JogFindings:
    """The direction that raised the tension, and the stiffness fitted over that jog's taut part."""
    tightened = next((t for t in traces if t.reached), None)
    if tightened is None:
        return JogFindings(None, None)
    taut = [(x, f) for x, f in tightened.points if f >= TAUT_FRACTION * target_n]
    return JogFindings(tightened.direction, fitted_slope(taut))


def fitted_slope(points: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of tension over line length [N/m]; None with too few or degenerate points."""
    if len(points) < MIN_FIT_POINTS:
        return None
    xs = [x for x, _ in points]
    ys = [y for _, y in points]
    mean_x, mean_y = statistics.fmean(xs), statistics.fmean(ys)
    sxx = sum((x - mean_x) ** 2 for x in xs)
    if sxx <= 0:
        return None
    slope = sum((x - mean_x) * (y - mean_y) for x, y in points) / sxx
    return slope if slope > 0 else None


def direction_row(
    ctx: CheckContext, traces: list[JogTrace], findings: JogFindings, target_n: float
) -> CheckRow:
    """Pass when reeling in the configured way raised the tension."""
    configured = ctx.config.reel_direction
    check = "reel direction (tension rises when reeling in)"
    found = findings.reel_direction
    if found == configured:
        measured = f"reel_direction {configured:+d}: the tension rose {target_n:g} N"
        return CheckRow(SECTION, check, Verdict.PASS, measured)
    if found is not None:
        measured = (
            f"reel_direction {configured:+d} paid line out; the tension rose only when the winch turned "
            f"the other way ({found:+d})"
        )
        fix = f"set reel_direction: {found} in {ctx.config.source} (`rig check --move --write` writes it)"
        return CheckRow(SECTION, check, Verdict.FAIL, measured, fix)
    rises = ", ".join(f"{t.direction:+d}: {t.rise_n:+.2f} N" for t in traces)
    travel = ctx.options.jog_travel_rev
    measured = f"the tension did not rise {target_n:g} N within {travel:g} rev either way ({rises})"
    fix = "take up the slack by hand until the line is nearly taut, and check that the cell is in the line"
    return CheckRow(SECTION, check, Verdict.FAIL, measured, fix)


def stiffness_row(ctx: CheckContext, findings: JogFindings) -> CheckRow:
    """The measured stiffness against the config's nominal one."""
    check = "line stiffness"
    nominal = ctx.config.line_stiffness_n_per_m
    measured_k = findings.stiffness_n_per_m
    if measured_k is None:
        return CheckRow(
            SECTION,
            check,
            Verdict.WARN,
            "not measured (the line did not tighten)",
            "see the reel direction row",
        )
    ratio = nominal / measured_k
    lo, hi = STIFFNESS_RATIO_OK
    measured = f"{measured_k:.0f} N/m measured; line_stiffness_n_per_m {nominal:g} N/m in the config"
    if lo <= ratio <= hi:
        return CheckRow(SECTION, check, Verdict.PASS, measured)
    fix = (
        f"set line_stiffness_n_per_m: {measured_k:.0f} (`rig check --move --write` writes it): the ramp's "
        "timeouts and the plan's durations come from it"
    )
    return CheckRow(SECTION, check, Verdict.WARN, measured, fix)
