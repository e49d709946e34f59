"""The safe-state sequence that ends every run, and the timeout and arrival of any commanded move.

Order matters and does not depend on which part failed: first the line is released (the winch
backs off to its zero-tension angle, through `ServoBus.shutdown(release)`, which then turns torque
off on every servo and closes the bus), then the load cell is closed, then the session. Each stage
runs even if an earlier one failed; every failure is collected, so the caller reports what
happened rather than what was attempted.
"""

from __future__ import annotations

from collections.abc import Callable

from rig.hw.session import RigSession

# A move gets twice the time its travel takes at the commanded speed, plus a margin: profiles
# accelerate, and the servo settles inside the position tolerance at the end.
MOVE_TIME_FACTOR = 2.0
POSITION_TOLERANCE_RAD = 0.02  # a servo within this of its goal has arrived


def move_timeout_s(travel_rad: float, speed_rad_s: float, margin_s: float) -> float:
    """How long a servo may take to travel `travel_rad` at `speed_rad_s` before the move timed out."""
    return abs(travel_rad) / speed_rad_s * MOVE_TIME_FACTOR + margin_s


def enter_safe_state(session: RigSession, release: Callable[[], None]) -> list[str]:
    """Release the line, torque off and close the bus, then close the load cell and the session.

    `release` backs the winch off; it runs inside the bus's shutdown, before torque goes off.
    Returns what failed, one text per stage (empty when every stage succeeded).
    """
    errors: list[str] = []
    release_errors: list[str] = []

    def guarded_release() -> None:
        try:
            release()
        except Exception as exc:  # keep going to torque off
            release_errors.append(f"release failed: {exc}")

    try:
        session.servos.shutdown(guarded_release)
    except Exception as exc:
        errors.append(f"torque off failed: {exc}")
    errors[:0] = release_errors
    try:
        session.load_cell.close()
    except Exception as exc:
        errors.append(f"load cell close failed: {exc}")
    return errors
