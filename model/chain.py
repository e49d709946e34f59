"""Statics of a chain of spherical joints (docs/model.md §3): kinematics, joint moments, tolerance, slip load.

Conventions (docs/model.md §1): joint i (1..J) is centred at the origin o_i of frame {i}; `T_i` (4x4) is the
pose of {i} in {i-1}; world poses `G_0 = I`, `G_i = G_{i-1} T_i`. The tip load is a force at point Q,
given in the tip frame {J}; forces and directions are given in the base frame {0}.

Every function is vectorised: arrays carry any leading batch dimensions, which broadcast between
the configurations (`transforms (..., J, 4, 4)`), the capacities `(..., J)`, the points `(..., 3)`
and the forces or directions `(..., 3)`. Per-joint outputs have J+1 entries, index 0 being the
base origin o_0 (not a joint) and index i joint i, so joint numbers index them directly.

The statics functions trust their transforms to be rigid motions (checking every matrix of a
large batch would cost more than the statics); validate untrusted input with `check_rigid_motion`,
as the link-file parser does. SI units; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from model.gravity import PAPER_G_M_S2

FloatArray = NDArray[np.float64]

# Two candidates within this relative distance of the minimum slip force count as tied.
SLIP_TIE_RTOL = 1e-12
# A lever arm this small relative to the link's size (the largest joint distance from Q) is rounding
# error: the joint is on the load's line of action (cross products of parallel vectors come out
# ~1e-17 relative, not 0). Relative to the link, not to each joint's own distance: a joint a few
# ulps from Q would otherwise keep an arm of 1e-150 m and slip under a load of 1e149 N.
ON_LOAD_LINE_RTOL = 1e-12


def _rot_x(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(c), np.zeros_like(c)
    return np.stack([one, zero, zero, zero, c, -s, zero, s, c], axis=-1).reshape(*c.shape, 3, 3)


def _rot_y(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, zero, s, zero, one, zero, -s, zero, c], axis=-1).reshape(*c.shape, 3, 3)


def _rot_z(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, -s, zero, s, c, zero, zero, zero, one], axis=-1).reshape(*c.shape, 3, 3)


def _homogeneous(rotation: FloatArray, translation: FloatArray) -> FloatArray:
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros((*shape, 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def pose_from_xyz_rpy(xyz: ArrayLike, rpy: ArrayLike) -> FloatArray:
    """Homogeneous pose (..., 4, 4) from a translation [m] and roll, pitch, yaw [rad].

    `R = Rz(yaw) · Ry(pitch) · Rx(roll)` (fixed-axis X, then Y, then Z).
    """
    xyz_a = np.asarray(xyz, dtype=float)
    rpy_a = np.asarray(rpy, dtype=float)
    if xyz_a.shape[-1:] != (3,) or rpy_a.shape[-1:] != (3,):
        raise ValueError(f"xyz shape {xyz_a.shape}, rpy shape {rpy_a.shape}; allowed: (..., 3) each")
    rotation = _rot_z(rpy_a[..., 2]) @ _rot_y(rpy_a[..., 1]) @ _rot_x(rpy_a[..., 0])
    return _homogeneous(rotation, xyz_a)


def check_rigid_motion(transform: ArrayLike, atol: float = 1e-6) -> FloatArray:
    """Return `transform` (..., 4, 4) as a float array if every matrix is a rigid motion, else raise.

    The `ValueError` says what is wrong: the shape, non-finite entries, a rotation that is not
    orthonormal (max |RᵀR − I| > atol), a reflection (det R != +1), or a bottom row other than
    [0, 0, 0, 1]. For a batch it names the first offending index.
    """
    t = np.asarray(transform, dtype=float)
    if t.ndim < 2 or t.shape[-2:] != (4, 4):
        raise ValueError(f"transform has shape {t.shape}; allowed: a 4x4 homogeneous matrix")

    def where(bad: NDArray[np.bool_]) -> str:
        if t.ndim == 2:
            return ""
        return f" at index {tuple(int(i) for i in np.argwhere(bad)[0])}"

    finite = np.all(np.isfinite(t), axis=(-2, -1))
    if not np.all(finite):
        raise ValueError(f"transform has non-finite entries{where(~finite)}")
    bottom_error = np.max(np.abs(t[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])), axis=-1)
    if np.any(bottom_error > atol):
        bad = bottom_error > atol
        row = t[..., 3, :][bad][0].tolist()
        raise ValueError(f"transform bottom row is {row}{where(bad)}; allowed: [0, 0, 0, 1]")
    rotation = t[..., :3, :3]
    gram = np.swapaxes(rotation, -1, -2) @ rotation
    ortho_error = np.max(np.abs(gram - np.eye(3)), axis=(-2, -1))
    if np.any(ortho_error > atol):
        bad = ortho_error > atol
        raise ValueError(
            f"transform rotation block is not orthonormal{where(bad)} "
            f"(max |R^T R - I| = {float(ortho_error[bad][0]):.3g} > {atol:g})"
        )
    det = np.linalg.det(rotation)
    if np.any(det < 0):
        raise ValueError(
            f"transform rotation block has det {float(det[det < 0][0]):.3g}{where(det < 0)} "
            "(a reflection); allowed: det = +1"
        )
    return t


def _transforms(transforms: ArrayLike) -> FloatArray:
    t = np.asarray(transforms, dtype=float)
    if t.ndim < 3 or t.shape[-2:] != (4, 4) or t.shape[-3] < 1:
        raise ValueError(f"transforms have shape {t.shape}; allowed: (..., J, 4, 4) with J >= 1")
    return t


def forward_kinematics(transforms: ArrayLike) -> FloatArray:
    """World poses (..., J+1, 4, 4) of frames {0}..{J}: `G_0 = I`, `G_i = G_{i-1} T_i`."""
    t = _transforms(transforms)
    n_joints = t.shape[-3]
    poses = np.empty((*t.shape[:-3], n_joints + 1, 4, 4))
    poses[..., 0, :, :] = np.eye(4)
    for i in range(n_joints):
        poses[..., i + 1, :, :] = poses[..., i, :, :] @ t[..., i, :, :]
    return poses


def planar_transforms(joint_angles_rad: ArrayLike, segment_lengths_m: ArrayLike) -> FloatArray:
    """Planar chain (..., J, 4, 4): `T_i = [Rot_y(φ_i), (0, 0, L_i)]` (docs/model.md §1; §8 value 4).

    `segment_lengths_m` is a scalar or (J,), broadcasting against the angles.
    """
    angles = np.asarray(joint_angles_rad, dtype=float)
    if angles.ndim < 1:
        raise ValueError("joint_angles_rad must have a joint axis (..., J)")
    lengths = np.broadcast_to(np.asarray(segment_lengths_m, dtype=float), angles.shape)
    translation = np.zeros((*angles.shape, 3))
    translation[..., 2] = lengths
    return _homogeneous(_rot_y(angles), translation)


def _vectors(name: str, value: ArrayLike) -> FloatArray:
    array = np.asarray(value, dtype=float)
    if array.ndim < 1 or array.shape[-1] != 3:
        raise ValueError(f"{name} has shape {array.shape}; allowed: (..., 3)")
    return array


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Cross product over the last axis (faster than np.cross for large batches)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _origins_and_point(transforms: FloatArray, point_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Joint origins o_0..o_J (..., J+1, 3) and Q in the world (..., 3).

    Each joint's transforms are first copied into a contiguous slab: numpy's batched matmul is
    several times faster on those than on the strided views `transforms[..., i, :, :]`.
    """
    n_joints = transforms.shape[-3]
    batch = np.broadcast_shapes(transforms.shape[:-3], point_m.shape[:-1])
    origins = np.zeros((n_joints + 1, *transforms.shape[:-3], 3))
    pose = np.ascontiguousarray(transforms[..., 0, :, :])
    origins[1] = pose[..., :3, 3]
    for i in range(1, n_joints):
        pose = pose @ np.ascontiguousarray(transforms[..., i, :, :])
        origins[i + 1] = pose[..., :3, 3]
    point_w = origins[n_joints] + np.einsum("...jk,...k->...j", pose[..., :3, :3], point_m)
    return np.broadcast_to(np.moveaxis(origins, 0, -2), (*batch, n_joints + 1, 3)), point_w


def joint_moments_recursive(transforms: ArrayLike, point_m: ArrayLike, force_w: ArrayLike) -> FloatArray:
    """Moments `iN_i` (..., J+1, 3) [N·m] by the paper's recursion (eqs. 9-10), each in its frame {i}.

    Index 0 is N_0 (about the base origin, base frame); index i the moment joint i must hold.
    """
    t = _transforms(transforms)
    point = _vectors("point_m", point_m)
    force = _vectors("force_w", force_w)
    n_joints = t.shape[-3]
    # Rotation of each frame in the world, to bring the base-frame force into the tip frame.
    rotation = np.broadcast_to(np.eye(3), (*t.shape[:-3], 3, 3))
    for i in range(n_joints):
        rotation = rotation @ t[..., i, :3, :3]
    force_i = np.einsum("...kj,...k->...j", rotation, force)  # R_Jᵀ F_w
    moment_i = _cross(np.broadcast_to(point, force_i.shape), force_i)
    batch = np.broadcast_shapes(t.shape[:-3], point.shape[:-1], force.shape[:-1])
    moments = np.empty((*batch, n_joints + 1, 3))
    moments[..., n_joints, :] = moment_i
    for i in range(n_joints, 0, -1):
        r_i = t[..., i - 1, :3, :3]
        p_i = t[..., i - 1, :3, 3]
        force_i = np.einsum("...jk,...k->...j", r_i, force_i)
        moment_i = np.einsum("...jk,...k->...j", r_i, moment_i) + _cross(p_i, force_i)
        moments[..., i - 1, :] = moment_i
    return moments


def joint_moments_frame_free(transforms: ArrayLike, point_m: ArrayLike, force_w: ArrayLike) -> FloatArray:
    """Moments (..., J+1, 3) [N·m] about o_0..o_J, all in the base frame: `(Q_w − o_i) × F_w`."""
    t = _transforms(transforms)
    point = _vectors("point_m", point_m)
    force = _vectors("force_w", force_w)
    origins, point_w = _origins_and_point(t, point)
    return _cross(point_w[..., None, :] - origins, force[..., None, :])


def joint_moment_norms(transforms: ArrayLike, point_m: ArrayLike, force_w: ArrayLike) -> FloatArray:
    """‖N_i‖ (..., J+1) [N·m]: index 0 the base moment, index i what joint i must hold."""
    norms: FloatArray = np.linalg.norm(joint_moments_frame_free(transforms, point_m, force_w), axis=-1)
    return norms


def lever_arms_m(transforms: ArrayLike, point_m: ArrayLike, direction_w: ArrayLike) -> FloatArray:
    """Lever arms d_i = ‖(Q_w − o_i) × u‖ (..., J+1) [m] of a load along `direction_w` (normalised).

    An arm below `ON_LOAD_LINE_RTOL` × max_i ‖Q_w − o_i‖ (the link's size seen from Q) is rounding
    error of a point on the load's line of action and is returned as exactly 0. A zero direction
    raises `ValueError`.
    """
    t = _transforms(transforms)
    point = _vectors("point_m", point_m)
    direction = _vectors("direction_w", direction_w)
    norm = np.linalg.norm(direction, axis=-1, keepdims=True)
    if np.any(~np.isfinite(norm)) or np.any(norm == 0):
        raise ValueError("direction_w contains a zero or non-finite vector; allowed: a non-zero direction")
    origins, point_w = _origins_and_point(t, point)
    offsets = point_w[..., None, :] - origins
    arms = np.linalg.norm(_cross(offsets, (direction / norm)[..., None, :]), axis=-1)
    link_size = np.linalg.norm(offsets, axis=-1).max(axis=-1, keepdims=True)
    return np.where(arms <= ON_LOAD_LINE_RTOL * link_size, 0.0, arms)


def _capacities(capacities_nm: ArrayLike, n_joints: int) -> FloatArray:
    capacities = np.asarray(capacities_nm, dtype=float)
    if capacities.ndim < 1 or capacities.shape[-1] != n_joints:
        raise ValueError(f"capacities_nm has shape {capacities.shape}; allowed: (..., {n_joints})")
    if np.any(np.isnan(capacities)) or np.any(capacities <= 0):
        raise ValueError("capacities_nm must be > 0 (inf allowed for a joint that never slips)")
    return capacities


def tolerated(
    transforms: ArrayLike,
    capacities_nm: ArrayLike,
    point_m: ArrayLike,
    force_w: ArrayLike,
    rtol: float = 1e-9,
) -> NDArray[np.bool_]:
    """Corollary 1: True where every joint's moment is within its capacity, ‖N_i‖ <= N_i,max.

    A moment within `rtol` (relative) above its capacity still counts as held, so that the slip load
    returned by `predict_slip`, computed in floating point, is itself tolerated.
    """
    t = _transforms(transforms)
    capacities = _capacities(capacities_nm, t.shape[-3])
    norms = joint_moment_norms(t, point_m, force_w)[..., 1:]
    held: NDArray[np.bool_] = np.all(norms <= capacities * (1.0 + rtol), axis=-1)
    return held


@dataclass(frozen=True)
class SlipPrediction:
    """Corollary 2 for a batch of links and loads; every field carries the batch shape `...`.

    * `slip_force_n` (...): f* = min_i N_i,max / d_i, the load magnitude at which the first joint slips.
    * `slip_mass_kg` (...): f*/g, the maximum payload.
    * `first_slip_joint` (...) int: the argmin, 1-based. Ties (within `SLIP_TIE_RTOL` relative) go
      to the joint nearest the base; `tied_joints` marks every joint at its capacity at f*. A joint
      on the load's line (d_i = 0) holds any load; if every joint is on it, f* = inf and
      `first_slip_joint` = 0 (nothing slips), with moments at slip reported as 0 for those joints.
    * `tip_moment_nm` (...): f*·d_J, the tip joint's moment at slip, the link capacity (Definition 2).
    * `base_moment_nm` (...): f*·d_0, the load moment about the base origin at slip.
    * `lever_arms_m` (..., J+1) and `joint_moments_at_slip_nm` (..., J+1): index 0 the base origin,
      index i joint i.
    * `tied_joints` (..., J) bool: joints whose moment reaches their capacity at f*.
    * `g` the gravity used for the masses [m/s²].
    """

    slip_force_n: FloatArray
    slip_mass_kg: FloatArray
    first_slip_joint: NDArray[np.int64]
    tip_moment_nm: FloatArray
    base_moment_nm: FloatArray
    lever_arms_m: FloatArray
    joint_moments_at_slip_nm: FloatArray
    tied_joints: NDArray[np.bool_]
    g: float


def predict_slip(
    transforms: ArrayLike,
    capacities_nm: ArrayLike,
    point_m: ArrayLike,
    direction_w: ArrayLike,
    g: float = PAPER_G_M_S2,
) -> SlipPrediction:
    """Slip load, first joint to slip, link capacity and payload (Corollary 2), vectorised over a batch."""
    if not (math.isfinite(g) and g > 0):
        raise ValueError(f"g = {g!r}; allowed: finite and > 0")
    t = _transforms(transforms)
    capacities = _capacities(capacities_nm, t.shape[-3])
    arms = lever_arms_m(t, point_m, direction_w)
    batch = np.broadcast_shapes(arms.shape[:-1], capacities.shape[:-1])
    arms = np.broadcast_to(arms, (*batch, arms.shape[-1]))
    capacities = np.broadcast_to(capacities, (*batch, capacities.shape[-1]))

    joint_arms = arms[..., 1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        candidates = np.where(joint_arms > 0, capacities / joint_arms, np.inf)
    slip_force = np.min(candidates, axis=-1)
    finite = np.isfinite(slip_force)
    tied = finite[..., None] & (candidates <= slip_force[..., None] * (1.0 + SLIP_TIE_RTOL))
    first = np.where(finite, np.argmax(tied, axis=-1) + 1, 0).astype(np.int64)
    with np.errstate(invalid="ignore"):
        moments = np.where(arms > 0, slip_force[..., None] * arms, 0.0)
    return SlipPrediction(
        slip_force_n=np.asarray(slip_force),
        slip_mass_kg=np.asarray(slip_force / g),
        first_slip_joint=first,
        tip_moment_nm=moments[..., -1],
        base_moment_nm=moments[..., 0],
        lever_arms_m=arms,
        joint_moments_at_slip_nm=moments,
        tied_joints=tied,
        g=float(g),
    )
