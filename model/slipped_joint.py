"""Which joint moved in a slip, from the link's configuration measured before and after it.

Each joint's rotation between the two measurements is the angle of `R_before^T R_after` of its own
transform (3D; for a planar link the change of its angle about y). The joint that turned the most
is the one that slipped, provided it turned by more than `threshold_rad` (chosen above the
measurement noise); below it the answer is None: the measurements cannot tell.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike


def joint_rotations_rad(before: ArrayLike, after: ArrayLike) -> np.ndarray:
    """Each joint's rotation angle [rad] between two configurations (J, 4, 4) of the same link."""
    b = np.asarray(before, dtype=float)
    a = np.asarray(after, dtype=float)
    if b.shape != a.shape or b.ndim != 3 or b.shape[1:] != (4, 4):
        raise ValueError(f"transforms of shapes {b.shape} and {a.shape}; allowed: the same (J, 4, 4)")
    relative = np.einsum("jki,jkl->jil", b[:, :3, :3], a[:, :3, :3])  # R_b^T R_a per joint
    cosines = (np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0
    angles: np.ndarray = np.arccos(np.clip(cosines, -1.0, 1.0))
    return angles


def moved_joint(before: ArrayLike, after: ArrayLike, threshold_rad: float) -> int | None:
    """The 1-based joint that turned the most, if by more than `threshold_rad`; else None."""
    if not (math.isfinite(threshold_rad) and threshold_rad >= 0):
        raise ValueError(f"threshold_rad = {threshold_rad!r}; allowed: finite and >= 0")
    rotations = joint_rotations_rad(before, after)
    if rotations.size == 0:
        return None
    worst = int(np.argmax(rotations))
    return worst + 1 if rotations[worst] > threshold_rad else None


def noise_threshold_rad(uncertainty_rad: float | None, floor_rad: float = math.radians(0.3)) -> float:
    """A rotation noise of `uncertainty_rad` per angle rarely reaches (4 sd of a difference)."""
    if uncertainty_rad is None:
        return floor_rad
    return max(floor_rad, 4.0 * math.sqrt(2.0) * uncertainty_rad)
