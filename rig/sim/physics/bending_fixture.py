"""The simulated bending fixture: one bender servo that sets the link's configuration and resets it.

An honest simplification of "bender servos push the link into a configuration": the fixture is
driven by **one** bender servo whose travel is proportional to the requested total bend,

    bender goal = rest angle + travel_per_bend · Σ_i |φ_i|     (a reset's goal is the rest angle)

so a bigger bend takes longer, which is what matters for a protocol's timing. While the bender
travels, the fixture holds the link (no joint can slip) and the configuration moves from where it
was toward the request in proportion to the bender's progress (updated by the world every few tens
of ms). When the bender reaches its goal (within the arrival tolerance) the fixture lets go and the
configuration becomes the requested joint angles plus an independent placement error N(0, σ_bend)
per joint; a reset puts the link against a straight stop, so it ends exactly straight. The fixture
only produces planar configurations (rotations about y); requesting a bend while the link is out of
plane (after a torsion slip) starts the interpolation from straight.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class BendingFixture:
    """Maps bender-servo travel to link configurations; see the module docstring."""

    def __init__(
        self,
        joint_count: int,
        *,
        rest_angle_rad: float,
        travel_per_bend: float,
        arrival_tolerance_rad: float,
        sigma_bend_rad: float,
        rng: np.random.Generator,
    ) -> None:
        self.joint_count = joint_count
        self.rest_angle_rad = float(rest_angle_rad)
        self.travel_per_bend = float(travel_per_bend)
        self.arrival_tolerance_rad = float(arrival_tolerance_rad)
        self.sigma_bend_rad = float(sigma_bend_rad)
        self._rng = rng
        self.moving = False
        self.goal_rad = self.rest_angle_rad
        self._start_bender_rad = self.rest_angle_rad
        self._start_angles = np.zeros(joint_count)
        self._target_angles = np.zeros(joint_count)
        self._exact = True

    def goal_for(self, joint_angles_rad: Sequence[float] | np.ndarray) -> float:
        """The bender angle that sets `joint_angles_rad`."""
        return self.rest_angle_rad + self.travel_per_bend * float(np.sum(np.abs(joint_angles_rad)))

    def request(
        self,
        joint_angles_rad: Sequence[float],
        current_angles_rad: Sequence[float] | None,
        bender_angle_rad: float,
        *,
        reset: bool = False,
    ) -> float:
        """Start moving toward `joint_angles_rad` (a reset: straight, exactly); returns the bender goal."""
        target = np.asarray(joint_angles_rad, dtype=float)
        if target.shape != (self.joint_count,) or not np.all(np.isfinite(target)):
            raise ValueError(f"joint angles {target.tolist()}; allowed: {self.joint_count} finite numbers")
        if reset and np.any(target != 0.0):
            raise ValueError("a reset goes to the straight configuration (all joint angles 0)")
        start = np.zeros(self.joint_count) if current_angles_rad is None else current_angles_rad
        self._start_angles = np.asarray(start, dtype=float)
        self._target_angles = target
        self._start_bender_rad = float(bender_angle_rad)
        self.goal_rad = self.goal_for(target)
        self._exact = reset
        self.moving = True
        return self.goal_rad

    def update(self, bender_angle_rad: float) -> tuple[np.ndarray | None, bool]:
        """Configuration for the bender's present angle: (joint angles or None if idle, arrived now)."""
        if not self.moving:
            return None, False
        if abs(bender_angle_rad - self.goal_rad) <= self.arrival_tolerance_rad:
            self.moving = False
            final = self._target_angles.copy()
            if not self._exact and self.sigma_bend_rad > 0:
                final += self._rng.normal(0.0, self.sigma_bend_rad, self.joint_count)
            return final, True
        travel = self.goal_rad - self._start_bender_rad
        fraction = 0.0 if travel == 0 else (bender_angle_rad - self._start_bender_rad) / travel
        fraction = min(1.0, max(0.0, fraction))
        return self._start_angles + fraction * (self._target_angles - self._start_angles), False
