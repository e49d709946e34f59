"""Interlocks: small checks run on every control tick; any that trips stops the run safely.

Each returns a reason string (with the measured value, the limit and units) or None. The runner
raises `InterlockTripped` with that reason, and its `finally` releases the line and turns torque
off. Load-cell staleness is raised by the load-cell driver itself (`StaleDataError`) and treated
the same way; step timeouts are deadlines the runner computes from each step's motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.hw.dxl.error_codes import describe_hardware_error
from rig.hw.seams import ServoState
from rig.vocabulary import ServoRole


@dataclass
class ForceCeiling:
    """Line tension above the ceiling (the smaller of the rig's and the protocol's)."""

    ceiling_n: float

    def check(self, max_force_n: float) -> str | None:
        """Trip when the largest tension seen this tick exceeds the ceiling."""
        if max_force_n > self.ceiling_n:
            return f"tension {max_force_n:.2f} N above the ceiling {self.ceiling_n:.2f} N"
        return None


@dataclass
class ServoHealth:
    """Any servo reporting a latched hardware error (overload, overheating, voltage, ...)."""

    roles: dict[int, ServoRole]

    def check(self, states: dict[int, ServoState]) -> str | None:
        """Trip on the first servo whose Hardware Error Status is non-zero."""
        for servo_id, state in states.items():
            if state.hardware_error:
                words = describe_hardware_error(state.hardware_error)
                role = self.roles.get(servo_id, "?")
                return f"servo {servo_id} ({role}) hardware error 0x{state.hardware_error:02X}: {words}"
        return None


@dataclass
class CurrentAtLimit:
    """The winch current held at its limit for longer than allowed (stalled against the line)."""

    winch_id: int
    limit_a: float
    hold_s: float
    fraction: float = 0.97
    _since_ns: int | None = field(default=None, init=False)

    def check(self, states: dict[int, ServoState], now_ns: int) -> str | None:
        """Trip when |current| >= fraction * limit continuously for `hold_s`."""
        state = states.get(self.winch_id)
        if state is None or abs(state.current_a) < self.fraction * self.limit_a:
            self._since_ns = None
            return None
        if self._since_ns is None:
            self._since_ns = now_ns
        held_s = (now_ns - self._since_ns) / 1e9
        if held_s >= self.hold_s:
            return (
                f"winch current {abs(state.current_a):.3f} A at its limit {self.limit_a:.3f} A "
                f"for {held_s:.2f} s (allowed {self.hold_s:.2f} s)"
            )
        return None
