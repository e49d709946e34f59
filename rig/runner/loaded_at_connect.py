"""A line found loaded at connect: paid out in small steps, each one checked on the load cell.

At connect nobody has verified the reel direction yet (`rig check --move` needs a slack line), so a
loaded line is never paid out by a computed travel in a direction taken on trust: with the
direction wrong that would reel in. Instead the winch pays out one small step at a time and the
cell is read after each. The steps go on while the tension falls, until the cell reads within
`limits.zero_tolerance_n` and a further step no longer lowers it: the line is slack (or the payout
reaches three times what the nominal stiffness says the reading needs, within the travel limit).
A step that raises the tension means the direction is wrong: the winch goes back to where it
started and pays out the other way, step by step, checked the same way (a step that raises it both
ways ends it there). No change over `limits.direction_check_rev` stops it too. Either way the run
then stops (exit 1); the safe state's load-cell check says whether the line ended slack.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from rig.records import LogLevel, ServoCommandName
from rig.runner.step_context import StepContext
from rig.safety.safe_state import POSITION_TOLERANCE_RAD, move_timeout_s

# A step is sized to lower the tension by this share of the zero tolerance at the nominal stiffness.
STEP_TOLERANCE_SHARE = 0.5
MAX_STEP_REV = 0.05  # and never more than this much of a turn
# A change of the averaged tension by this share of the zero tolerance is a change, not noise.
CHANGE_TOLERANCE_SHARE = 0.25
# The cell is averaged over at least this long, and at least this many samples, after each step.
AVERAGE_S = 0.1
AVERAGE_SAMPLES = 3
# A line softer than its nominal stiffness needs more travel than the reading suggests.
PAYOUT_FACTOR = 3.0


class PayoutVerdict(StrEnum):
    """How a stepwise payout ended."""

    SLACK = "slack"  # the cell reads within the zero tolerance and a further step no longer lowers it
    RISES_BOTH_WAYS = "rises_both_ways"  # a step either way raised the tension: back at the start
    NO_CHANGE = "no_change"  # the tension did not change over the direction check's travel
    STILL_LOADED = "still_loaded"  # the tension fell, but not to the tolerance within the payout
    NO_READING = "no_reading"  # the load cell stopped giving samples


@dataclass(frozen=True)
class PayoutResult:
    """Where a stepwise payout left the winch and the line."""

    verdict: PayoutVerdict
    start_n: float
    end_n: float
    paid_out_rad: float  # from where the winch stood at connect, in the direction that lowered the tension
    position_rad: float  # where the winch holds now (its zero-tension angle for the safe state)
    reversed: bool  # paying out by `reel_direction` raised the tension: the other way lowered it

    def describe(self) -> str:
        """What happened, for the run's reason and log."""
        moved = f"paid out {self.paid_out_rad:.2f} rad in small steps"
        if self.reversed:
            moved = (
                "a small step paying out by reel_direction raised the tension, so reel_direction is "
                f"probably wrong; turning the other way instead it {moved}"
            )
        match self.verdict:
            case PayoutVerdict.SLACK:
                return f"{moved}, the tension falling from {self.start_n:+.2f} N to {self.end_n:+.2f} N"
            case PayoutVerdict.RISES_BOTH_WAYS:
                return (
                    f"a small step either way raised the tension (from {self.start_n:+.2f} N, to "
                    f"{self.end_n:+.2f} N last): the winch went back to where it stood and holds there"
                )
            case PayoutVerdict.NO_CHANGE:
                return (
                    f"{moved} and the tension stayed at {self.end_n:+.2f} N (from {self.start_n:+.2f} N): "
                    "the load is not on this winch's line, or the cell's zero is off"
                )
            case PayoutVerdict.STILL_LOADED:
                return f"{moved}, the tension falling from {self.start_n:+.2f} N only to {self.end_n:+.2f} N"
            case PayoutVerdict.NO_READING:
                return f"{moved}; then the load cell gave no reading"


def pay_out_verified(ctx: StepContext, reading_n: float) -> PayoutResult:
    """Pay the line out step by step while the cell shows the tension falling; see the module docstring.

    `ctx.winch_zero_rad` follows the step with the lowest tension measured so far, so a fault in the
    middle of the payout leaves the safe state going there, never back to the line as loaded; at the
    end it is where the winch holds, so the safe state does not move it again.
    """
    loop, config = ctx.loop, ctx.config
    limits = config.limits
    winch = ctx.session.winch_id
    servos = ctx.session.servos
    out = -config.reel_direction  # paying out, in the winch's position sense
    tolerance_n = limits.zero_tolerance_n
    n_per_rad = ctx.line_stiffness_n_per_m * config.spool_radius_m
    step_rad = min(STEP_TOLERANCE_SHARE * tolerance_n / n_per_rad, MAX_STEP_REV * 2 * math.pi)
    check_rad = limits.direction_check_rev * 2 * math.pi
    travel_rad = limits.max_winch_travel_rev * 2 * math.pi
    max_payout_rad = min(max(PAYOUT_FACTOR * reading_n / n_per_rad, check_rad), travel_rad)
    change_n = CHANGE_TOLERANCE_SHARE * tolerance_n
    speed = ctx.protocol.ramp.unload_speed_rad_s
    start_rad = loop.states[winch].position_rad
    servos.set_profile(winch, velocity_rad_s=speed)

    def move_to(goal_rad: float) -> None:
        servos.write_goal_positions({winch: goal_rad})
        ctx.recorder.command(winch, ServoCommandName.GOAL_POSITION, goal_rad, "rad")
        travel = abs(loop.states[winch].position_rad - goal_rad)

        def arrived() -> bool:
            state = loop.states[winch]
            return abs(state.position_rad - goal_rad) < POSITION_TOLERANCE_RAD and not state.moving

        loop.wait_until(
            arrived,
            move_timeout_s(travel, speed, ctx.protocol.step_timeout_margin_s),
            "pay out",
            step=lambda: loop.tick(interlocks=False),
        )

    def averaged_n() -> float | None:
        forces: list[float] = []
        end_ns = loop.clock.monotonic_ns() + round(
            max(AVERAGE_S, AVERAGE_SAMPLES / ctx.loadcell_rate_hz) * 1e9
        )
        while loop.clock.monotonic_ns() < end_ns or 0 < len(forces) < AVERAGE_SAMPLES:
            loop.tick(interlocks=False)
            forces += [s.force_n for s in loop.tick_samples]
            if loop.clock.monotonic_ns() > end_ns + round(1e9):  # a second past: the cell is silent
                break
        return sum(forces) / len(forces) if forces else None

    force_n = lowest_n = reading_n
    paid_rad = 0.0
    falling = False
    flipped = False
    verdict = PayoutVerdict.STILL_LOADED
    while True:
        paid_rad = min(paid_rad + step_rad, max_payout_rad)
        move_to(start_rad + out * paid_rad)
        measured = averaged_n()
        if measured is None:
            verdict = PayoutVerdict.NO_READING
            break
        step_change_n = force_n - measured
        force_n = measured
        if force_n < lowest_n:  # should anything fail from here on, the safe state goes back here
            lowest_n, ctx.winch_zero_rad = force_n, start_rad + out * paid_rad
        if force_n <= tolerance_n and (step_change_n < change_n or paid_rad >= max_payout_rad):
            verdict = PayoutVerdict.SLACK  # within the tolerance, and paying out no longer lowers it
            break
        if force_n >= reading_n + change_n:
            move_to(start_rad)
            paid_rad, force_n = 0.0, reading_n
            if flipped:
                verdict = PayoutVerdict.RISES_BOTH_WAYS
                break
            # Reeling in, not paying out: the direction is wrong, and the other way is the payout.
            flipped, out, falling = True, -out, False
            continue
        falling = falling or force_n <= reading_n - change_n
        if not falling and paid_rad >= check_rad:
            verdict = PayoutVerdict.NO_CHANGE
            break
        if paid_rad >= max_payout_rad:
            break
    ctx.winch_zero_rad = loop.states[winch].position_rad
    result = PayoutResult(verdict, reading_n, force_n, paid_rad, ctx.winch_zero_rad, flipped)
    level = LogLevel.INFO if verdict == PayoutVerdict.SLACK else LogLevel.WARNING
    ctx.recorder.note(level, f"line loaded at connect: {result.describe()}")
    return result
