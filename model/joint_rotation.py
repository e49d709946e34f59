"""Joint rotations from the measured poses of a link's components, and their planar projection.

A camera (or any pose sensor) gives each component's orientation in one common frame. Joint i's
rotation is that of {i} in {i−1} (docs/model.md §1): `R_i = W_{i−1}ᵀ W_i`, W_k the orientation of
component k in the common frame. Its *planar angle* is the projection onto a rotation about y (the
planar configurations of §1, `T_i = [Rot_y(φ_i), (0, 0, L_i)]`): the direction of component i's axis
z, seen in {i−1}, projected onto {i−1}'s x–z plane, `φ_i = atan2(R_i[0, 2], R_i[2, 2])`. What is
left, `Rot_y(φ_i)ᵀ R_i`, is the joint's out-of-plane rotation (a tilt out of the bending plane and a
twist about the axis); its angle is zero exactly when the joint turned about y only.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def rotation_angle_rad(rotation: ArrayLike) -> float:
    """The angle [0, π] of a rotation matrix, from its skew part and trace (accurate near 0 and π)."""
    r = np.asarray(rotation, dtype=float)
    skew = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return float(np.arctan2(0.5 * np.linalg.norm(skew), 0.5 * (np.trace(r) - 1.0)))


def rotation_vector(rotation: ArrayLike) -> FloatArray:
    """The rotation vector (axis × angle [rad]) of a rotation matrix; for angles below about 3 rad."""
    r = np.asarray(rotation, dtype=float)
    skew = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    angle = rotation_angle_rad(r)
    sine = float(np.linalg.norm(skew))
    return skew if sine < 1e-12 else skew * (angle / sine)


def out_of_plane_vector(rotation: ArrayLike) -> FloatArray:
    """(x, z) components of the rotation vector of `Rot_y(φ)ᵀ R`: the tilt and the twist, in rad."""
    r = np.asarray(rotation, dtype=float)
    residual = rot_y(float(np.arctan2(r[0, 2], r[2, 2]))).T @ r
    vector = rotation_vector(residual)
    return np.array([vector[0], vector[2]])


def joint_rotations(component_rotations: ArrayLike) -> FloatArray:
    """(J, 3, 3) rotations of {i} in {i−1} from (J+1, 3, 3) orientations of components 0..J."""
    w = np.asarray(component_rotations, dtype=float)
    if w.ndim != 3 or w.shape[1:] != (3, 3) or w.shape[0] < 2:
        raise ValueError(f"component rotations must have shape (J+1, 3, 3) with J >= 1, got {w.shape}")
    return np.asarray(np.einsum("kji,kjl->kil", w[:-1], w[1:]), dtype=np.float64)


def rot_y(angle_rad: float) -> FloatArray:
    """The rotation by `angle_rad` about y (the planar joints' axis)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def planar_projection(rotations: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(planar angles φ_i [rad], out-of-plane angles [rad]) of (J, 3, 3) joint rotations; see the module."""
    r = np.asarray(rotations, dtype=float)
    angles = np.arctan2(r[:, 0, 2], r[:, 2, 2])
    residual = np.array([rotation_angle_rad(rot_y(float(a)).T @ ri) for a, ri in zip(angles, r, strict=True)])
    return angles, residual


def joint_transforms(rotations: ArrayLike, segment_lengths_m: ArrayLike) -> FloatArray:
    """(J, 4, 4) poses `T_i = [R_i, (0, 0, L_i)]` of {i} in {i−1}: the ball centre fixed in its socket."""
    r = np.asarray(rotations, dtype=float)
    lengths = np.asarray(segment_lengths_m, dtype=float)
    if r.shape[0] != lengths.shape[0]:
        raise ValueError(f"{r.shape[0]} rotations but {lengths.shape[0]} segment lengths")
    t = np.zeros((r.shape[0], 4, 4))
    t[:, :3, :3] = r
    t[:, 2, 3] = lengths
    t[:, 3, 3] = 1.0
    return t
