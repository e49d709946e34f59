"""The winch drum and the line (with an optional series spring) from the winch to the acting point.

Sign convention: the winch's output-shaft angle θ increases when it **reels in** (shortens the
line). The line is taut from θ_slack on:

    tension = k_eff · max(0, r_drum · (θ − θ_slack) − take_up)

where `take_up` is how far the acting point has moved toward the winch since the reference
configuration (slips and bending, from `ChainLink.take_up_m`) and `k_eff` is the line and the
spring in series, `1/k_eff = 1/k_line + 1/k_spring`. The line only pulls (tension ≥ 0) and has no
mass or damping. The tension acts on the drum as an **external torque of −tension·r_drum** on the
winch shaft: it opposes reeling in (a positive torque would turn the shaft toward larger θ).
"""

from __future__ import annotations

import math


class WinchLine:
    """Tension of a drum-and-line (optionally with a spring) as a function of the winch angle."""

    def __init__(
        self,
        drum_radius_m: float,
        line_stiffness_n_per_m: float,
        spring_stiffness_n_per_m: float | None = None,
        slack_angle_rad: float = 0.0,
    ) -> None:
        if not drum_radius_m > 0 or not line_stiffness_n_per_m > 0:
            raise ValueError("drum_radius_m and line_stiffness_n_per_m must be > 0")
        if spring_stiffness_n_per_m is not None and not spring_stiffness_n_per_m > 0:
            raise ValueError("spring_stiffness_n_per_m must be > 0 or None")
        self.drum_radius_m = float(drum_radius_m)
        self.line_stiffness_n_per_m = float(line_stiffness_n_per_m)
        self.spring_stiffness_n_per_m = spring_stiffness_n_per_m
        if spring_stiffness_n_per_m is None:
            self.stiffness_n_per_m = self.line_stiffness_n_per_m
        else:
            self.stiffness_n_per_m = 1.0 / (1.0 / line_stiffness_n_per_m + 1.0 / spring_stiffness_n_per_m)
        self.slack_angle_rad = float(slack_angle_rad)

    def stretch_m(self, winch_angle_rad: float, take_up_m: float) -> float:
        """Elongation of line plus spring (negative: slack) [m]."""
        return self.drum_radius_m * (winch_angle_rad - self.slack_angle_rad) - take_up_m

    def tension_n(self, winch_angle_rad: float, take_up_m: float) -> float:
        """Line tension [N] (0 while slack)."""
        stretch = self.drum_radius_m * (winch_angle_rad - self.slack_angle_rad) - take_up_m
        return self.stiffness_n_per_m * stretch if stretch > 0.0 else 0.0

    def winch_torque_nm(self, tension_n: float) -> float:
        """External torque of the line on the winch shaft [N·m]: −tension·r_drum (opposes reeling in)."""
        return -tension_n * self.drum_radius_m

    def winch_angle_for_tension_rad(self, tension_n: float, take_up_m: float) -> float:
        """The winch angle at which the tension is `tension_n` (> 0), for a given take-up."""
        if not (math.isfinite(tension_n) and tension_n > 0):
            raise ValueError(f"tension_n = {tension_n!r}; allowed: finite and > 0")
        return self.slack_angle_rad + (tension_n / self.stiffness_n_per_m + take_up_m) / self.drum_radius_m
