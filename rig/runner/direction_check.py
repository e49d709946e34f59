"""The reel direction, verified by every ramp: reeling in must raise the tension.

A drum wound the other way (`reel_direction` wrong) pays line out while the ramp believes it reels
in: the tension never rises and the ramp would turn on until its timeout, turns of line later. So
each ramp watches the winch's travel in the reel-in sense from where the ramp began: once it has
turned `limits.direction_check_rev` with the tension risen less than `limits.zero_tolerance_n`,
the run stops (exit 1, safe state) and says how to find the direction. `rig check --move` finds it
on a slack line before a run; this check is what catches a run started without it.

Once a ramp of the run has seen the tension rise, the direction is verified for the rest of the
invocation (a winch cannot change its direction mid-run); a later ramp that meets slack (a link
that slid far in the trial before) is then bounded by its timeout and the winch's travel, as before.
"""

from __future__ import annotations

import math

from rig.errors import WinchDirectionError
from rig.inputs.rig_config import RigConfig


class ReelDirectionCheck:
    """Watches one ramp until the tension has risen (verified) or the winch has turned too far (raises)."""

    def __init__(
        self,
        config: RigConfig,
        trial_id: int,
        start_reel_rad: float,
        start_force_n: float,
        *,
        verified: bool = False,
    ) -> None:
        self.config = config
        self.trial_id = trial_id
        self.start_reel_rad = start_reel_rad  # the winch's position in the reel-in sense at the start
        self.start_force_n = start_force_n
        self.travel_rad = config.limits.direction_check_rev * 2 * math.pi
        self.rise_n = config.limits.zero_tolerance_n
        self.verified = verified

    def update(self, reel_rad: float, force_n: float) -> bool:
        """One tick: the winch's position (reel-in sense) and the tension; whether the direction is verified.

        WinchDirectionError when the winch has turned the check's travel without the tension rising.
        """
        if self.verified:
            return True
        rise_n = force_n - self.start_force_n
        if rise_n >= self.rise_n:
            self.verified = True
            return True
        turned_rad = reel_rad - self.start_reel_rad
        if turned_rad < self.travel_rad:
            return False
        config = self.config
        limits = config.limits
        raise WinchDirectionError(
            f"trial {self.trial_id}: the winch reeled in {turned_rad:.2f} rad "
            f"({turned_rad / (2 * math.pi):.2f} turn, limits.direction_check_rev "
            f"{limits.direction_check_rev:g}) "
            f"and the tension rose {rise_n:+.2f} N, less than limits.zero_tolerance_n "
            f"({limits.zero_tolerance_n:g} N): the winch is probably turning the wrong way. Check "
            f"reel_direction ({config.reel_direction:+d}) in {config.source}: on a slack line, "
            f"`rig check --rig {config.source} --move --write` measures the direction and writes it. "
            "Then start the run again: a run does not resume on a changed rig config. (A line off its "
            "drum, or more slack than that travel, stops a run the same way: take the slack up first)"
        )
