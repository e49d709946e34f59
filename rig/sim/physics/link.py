"""The simulated link: a chain of spherical joints, its geometry and each joint's slip criterion.

`ChainLink` holds the current configuration (transforms `T_i`, docs/model.md §1), the capacities in
force for the current trial, the acting point Q (tip frame) and the line direction u (base frame,
constant: the winch is far from the link, so the line keeps its direction as Q moves). The statics
come from `model.chain`; this module only adds what a simulator needs on top:

* **Slip criterion per unit force.** For a line tension f the moment about joint i is
  `f·m_i` with `m_i = (Q_w − o_i) × u` (`model.chain.joint_moments_frame_free` with a unit force).
  An isotropic joint (the paper's assumption) slips when `f·|m_i| > N_i`, i.e. its criterion per
  newton is `c_i = |m_i| / N_i`. The optional **torsion-weak joint** splits `m_i` into torsion
  `t = m_i · z_i` about the axis z_i of its own frame {i} (the axis of component i) and bending
  `b = m_i − t z_i`, and slips when `f·sqrt((|b|/N_i)² + (t/(α N_i))²) > 1`; α < 1 makes torsion
  weaker than bending, which breaks the paper's isotropy. The link slips at
  `f* = 1 / max_i c_i` (for isotropic joints exactly `model.chain.predict_slip`'s min N_i/d_i).
* **Slip motion.** A slipping joint turns about the flow direction of its criterion (the gradient
  with respect to the moment: `m_i/|m_i|` for an isotropic joint, `b/N² + t z/(αN)²` normalised for
  the torsion-weak one) at its centre o_i. Turning it by dφ about unit axis a moves Q toward the
  winch by `dx = a·m_i dφ` (for an isotropic joint a·m_i = d_i, the lever arm), which is what
  relieves the line. The new configuration is then exact (the rotation is applied to `T_i`).
* **Line take-up.** `take_up_m = u·(Q_w − Q_ref)`, the distance Q has moved toward the winch since
  the straight reference configuration; the winch line (`winch_line.py`) subtracts it from the
  reeled-in length. Slips and bending both change it.

Everything derived from the configuration is cached and recomputed only when it changes, so the
world's per-substep check is a single comparison with `slip_threshold_n`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from model.chain import forward_kinematics, joint_moments_frame_free, planar_transforms

PLANAR_TOLERANCE = 1e-9  # max |off-plane entry| of every rotation for a configuration to count as planar


def rotation_about_axis(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix (3, 3) about unit `axis` by `angle_rad` (Rodrigues)."""
    x, y, z = axis
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    v = 1.0 - c
    return np.array(
        [
            [c + x * x * v, x * y * v - z * s, x * z * v + y * s],
            [y * x * v + z * s, c + y * y * v, y * z * v - x * s],
            [z * x * v - y * s, z * y * v + x * s, c + z * z * v],
        ]
    )


class ChainLink:
    """A chain of J spherical joints under a line load; geometry plus per-joint slip criteria."""

    def __init__(
        self,
        segment_lengths_m: Sequence[float],
        point_m: Sequence[float],
        direction_w: Sequence[float],
        capacities_nm: Sequence[float],
        *,
        torsion_weak_joint: int | None = None,
        torsion_ratio: float = 1.0,
    ) -> None:
        self._lengths = np.asarray(segment_lengths_m, dtype=float)
        self.joint_count = len(self._lengths)
        self._point = np.asarray(point_m, dtype=float)
        direction = np.asarray(direction_w, dtype=float)
        self._direction = direction / np.linalg.norm(direction)
        if torsion_weak_joint is not None and not 1 <= torsion_weak_joint <= self.joint_count:
            raise ValueError(f"torsion_weak_joint = {torsion_weak_joint}; allowed: 1..{self.joint_count}")
        self.torsion_weak_joint = torsion_weak_joint
        self.torsion_ratio = float(torsion_ratio)
        self._capacities = np.ones(self.joint_count)
        self._transforms = planar_transforms(np.zeros(self.joint_count), self._lengths)
        self._ref_point_w = self._point_w(forward_kinematics(self._transforms))
        # Derived from the configuration and capacities (see _refresh).
        self.take_up_m = 0.0
        self.slip_threshold_n = math.inf
        self.governing_joint = 0  # 1-based joint that slips first; 0 if none can
        self._criteria_per_n = np.zeros(self.joint_count)
        self._unit_moments_w = np.zeros((self.joint_count + 1, 3))
        self._poses = np.zeros((self.joint_count + 1, 4, 4))
        self.set_capacities(capacities_nm)

    # --- configuration -------------------------------------------------------------------------
    @property
    def transforms(self) -> np.ndarray:
        """A copy of the current transforms (J, 4, 4)."""
        return self._transforms.copy()

    @property
    def point_m(self) -> tuple[float, float, float]:
        """Acting point Q in the tip frame."""
        return (float(self._point[0]), float(self._point[1]), float(self._point[2]))

    @property
    def direction_w(self) -> tuple[float, float, float]:
        """Unit line direction (from Q toward the winch) in the base frame."""
        return (float(self._direction[0]), float(self._direction[1]), float(self._direction[2]))

    @property
    def capacities_nm(self) -> tuple[float, ...]:
        """Capacities in force for the current trial (N·m), joint 1 first."""
        return tuple(float(c) for c in self._capacities)

    def set_joint_angles(self, joint_angles_rad: Sequence[float] | np.ndarray) -> None:
        """Set a planar configuration: `T_i = [Rot_y(φ_i), (0, 0, L_i)]`."""
        angles = np.asarray(joint_angles_rad, dtype=float)
        if angles.shape != (self.joint_count,) or not np.all(np.isfinite(angles)):
            raise ValueError(f"joint angles {angles.tolist()}; allowed: {self.joint_count} finite numbers")
        self._transforms = planar_transforms(angles, self._lengths)
        self._refresh()

    def set_point(self, point_m: Sequence[float], *, as_reference: bool = True) -> None:
        """Move the acting point (tip frame); with `as_reference`, the line's take-up restarts at 0 here."""
        self._point = np.asarray(point_m, dtype=float)
        if as_reference:
            self._ref_point_w = self._point_w(forward_kinematics(self._transforms))
        self._refresh()

    def set_capacities(self, capacities_nm: Sequence[float] | np.ndarray) -> None:
        """Set the capacities of this trial (N·m, > 0)."""
        caps = np.asarray(capacities_nm, dtype=float)
        if caps.shape != (self.joint_count,) or not np.all(caps > 0):
            raise ValueError(f"capacities {caps.tolist()}; allowed: {self.joint_count} numbers > 0")
        self._capacities = caps
        self._refresh()

    def planar_joint_angles(self) -> tuple[float, ...] | None:
        """φ_i if every joint rotation is about y (a planar configuration), else None."""
        r = self._transforms[:, :3, :3]
        off_plane = np.abs(r[:, [0, 1, 1, 2], [1, 0, 2, 1]]).max()
        if off_plane > PLANAR_TOLERANCE:
            return None
        return tuple(float(a) for a in np.arctan2(r[:, 0, 2], r[:, 0, 0]))

    def acting_point_w(self) -> np.ndarray:
        """Q in the base frame (3,)."""
        return self._point_w(self._poses)

    # --- slip --------------------------------------------------------------------------------
    def criterion_per_n(self, joint: int) -> float:
        """Criterion value of `joint` (1-based) per newton of line tension; it slips at f·c > 1."""
        return float(self._criteria_per_n[joint - 1])

    def criteria_per_n(self) -> tuple[float, ...]:
        """All joints' criteria per newton, joint 1 first."""
        return tuple(float(c) for c in self._criteria_per_n)

    def lever_arms_m(self) -> tuple[float, ...]:
        """Lever arms d_0..d_J of the line about o_0..o_J (index 0 the base origin)."""
        return tuple(float(x) for x in np.linalg.norm(self._unit_moments_w, axis=-1))

    def slip_flow(self, joint: int) -> tuple[np.ndarray, float]:
        """Unit rotation axis (base frame) of a slip of `joint`, and the take-up per rad [m/rad]."""
        moment = self._unit_moments_w[joint]
        if joint == self.torsion_weak_joint:
            cap = self._capacities[joint - 1]
            z_axis = self._poses[joint, :3, 2]
            torsion = float(moment @ z_axis)
            bending = moment - torsion * z_axis
            flow = bending / cap**2 + z_axis * (torsion / (self.torsion_ratio * cap) ** 2)
        else:
            flow = moment
        norm = float(np.linalg.norm(flow))
        if norm == 0.0:
            return np.array([0.0, 1.0, 0.0]), 0.0
        axis = flow / norm
        return axis, float(axis @ moment)

    def rotate_joint(self, joint: int, axis_w: np.ndarray, angle_rad: float) -> None:
        """Turn component `joint` (and everything distal) about o_joint by `angle_rad` about `axis_w`."""
        parent_rotation = self._poses[joint - 1, :3, :3]
        axis_local = parent_rotation.T @ axis_w
        transforms = self._transforms.copy()
        turn = rotation_about_axis(axis_local, angle_rad)
        transforms[joint - 1, :3, :3] = turn @ transforms[joint - 1, :3, :3]
        self._transforms = transforms
        self._refresh()

    # --- internals ---------------------------------------------------------------------------
    def _point_w(self, poses: np.ndarray) -> np.ndarray:
        tip = poses[-1]
        point: np.ndarray = tip[:3, :3] @ self._point + tip[:3, 3]
        return point

    def _refresh(self) -> None:
        self._poses = forward_kinematics(self._transforms)
        self._unit_moments_w = joint_moments_frame_free(self._transforms, self._point, self._direction)
        joint_moments = self._unit_moments_w[1:]
        criteria = np.linalg.norm(joint_moments, axis=-1) / self._capacities
        weak = self.torsion_weak_joint
        if weak is not None:
            cap = self._capacities[weak - 1]
            z_axis = self._poses[weak, :3, 2]
            moment = joint_moments[weak - 1]
            torsion = float(moment @ z_axis)
            bending = float(np.linalg.norm(moment - torsion * z_axis))
            criteria[weak - 1] = math.hypot(bending / cap, torsion / (self.torsion_ratio * cap))
        self._criteria_per_n = criteria
        worst = int(np.argmax(criteria))
        if criteria[worst] > 0:
            self.slip_threshold_n = float(1.0 / criteria[worst])
            self.governing_joint = worst + 1
        else:
            self.slip_threshold_n = math.inf
            self.governing_joint = 0
        self.take_up_m = float(self._direction @ (self._point_w(self._poses) - self._ref_point_w))
