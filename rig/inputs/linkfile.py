"""The link file (docs/formats.md §3): a deformable link's geometry, joint capacities and tip load, validated.

Used by `rig predict` and, through `parse_link`, by the `article:` section of rig configs. Every bad
input raises `InputError` with one line: the file, the field path (e.g. `joints[2].transform`, the
list index is 0-based, the joint number 1-based) and what is allowed.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from model.chain import check_rigid_motion, pose_from_xyz_rpy
from model.gravity import PAPER_G_M_S2
from model.joint import CapacityConstant, joint_capacity_nm, resolve_constant
from rig.errors import InputError
from rig.inputs.files import load_yaml_file

_TOP_KEYS = ("g", "joints", "load")
_JOINT_KEYS = ("transform", "xyz", "rpy", "capacity_nm", "radius_m", "mu_delta0_pa", "constant")
_LOAD_KEYS = ("point_m", "direction", "force_n")

# Physically sensible ranges (docs/formats.md §3): wide for any bench link, narrow enough that no
# product or quotient of them overflows or underflows to a subnormal on the way to the output.
G_RANGE = (0.1, 100.0)  # m/s²
CAPACITY_RANGE_NM = (1e-6, 1e4)
RADIUS_RANGE_M = (1e-5, 1.0)
MU_DELTA0_RANGE_PA = (1.0, 1e12)
CONSTANT_RANGE = (1e-3, 1e3)
LENGTH_LIMIT_M = 10.0  # |each coordinate| of translations and the acting point
ANGLE_LIMIT_RAD = 10.0  # |roll|, |pitch|, |yaw|
DIRECTION_LIMIT = 1e3  # |each component| of `direction`
FORCE_LIMIT_N = 1e5  # |each component| of `force_n`
MIN_VECTOR_NORM = 1e-6
MAX_JOINTS = 100


@dataclass(frozen=True)
class CapacitySource:
    """Where one joint's capacity came from.

    `kind` is 'capacity_nm' (given directly) or 'radius_mu_delta0' (computed as c·μs·δ0·R³, with
    `radius_m`, `mu_delta0_pa` and the `constant` used).
    """

    joint: int
    kind: Literal["capacity_nm", "radius_mu_delta0"]
    capacity_nm: float
    radius_m: float | None = None
    mu_delta0_pa: float | None = None
    constant: CapacityConstant | None = None

    def describe(self) -> str:
        """Short provenance, e.g. 'c·μsδ0·R³: R=0.01 m, μsδ0=1.6e+05 Pa, c=paper (5.4397)'."""
        if self.kind == "capacity_nm":
            return "given"
        assert self.constant is not None
        return (
            f"c·μsδ0·R³: R={self.radius_m:g} m, μsδ0={self.mu_delta0_pa:.6g} Pa, "
            f"c={self.constant.name} ({self.constant.value:g})"
        )


@dataclass(frozen=True)
class LinkSpec:
    """A validated link file.

    * `transforms` (J, 4, 4): pose of {i} in {i-1}, base to tip; rigid motions.
    * `capacities_nm` (J,): joint capacities [N·m]; `capacity_sources` says where each came from.
    * `point_m` (3,): acting point Q in the tip frame [m].
    * `direction_w` (3,): unit load direction in the base frame (from `direction`, or `force_n`
      normalised); `force_n` (3,) the load in the base frame [N] when the file gives one, else None.
    * `g` [m/s²]; `source` the file (or description) it was read from.
    """

    source: str
    transforms: NDArray[np.float64]
    capacities_nm: NDArray[np.float64]
    capacity_sources: tuple[CapacitySource, ...]
    point_m: NDArray[np.float64]
    direction_w: NDArray[np.float64]
    force_n: NDArray[np.float64] | None
    g: float

    @property
    def n_joints(self) -> int:
        """Number of joints J."""
        return int(self.capacities_nm.shape[0])


class _Context:
    """Builds one-line `InputError`s naming the source and a field path."""

    def __init__(self, source: str, prefix: str) -> None:
        self.source = source
        self.prefix = prefix

    def error(self, field: str, problem: str, allowed: str) -> InputError:
        path = f"{self.prefix}{field}" if field else (self.prefix.rstrip(".") or "(top level)")
        return InputError(f"{self.source}: {path}: {problem}; allowed: {allowed}")


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _number(ctx: _Context, field: str, value: Any, allowed: str) -> float:
    """A finite real number; numeric strings (YAML 1.1 reads `1e5` as a string) are accepted."""
    if isinstance(value, bool) or value is None:
        raise ctx.error(field, f"{_describe(value)} is not a number", allowed)
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            raise ctx.error(field, f"{_describe(value)} is not a number", allowed) from None
    elif isinstance(value, int | float):
        try:
            number = float(value)
        except OverflowError:  # an integer beyond the float range
            raise ctx.error(field, "an integer beyond the float range is out of range", allowed) from None
    else:
        raise ctx.error(field, f"{_describe(value)} is not a number", allowed)
    if not math.isfinite(number):
        raise ctx.error(field, f"{_describe(value)} is not finite", allowed)
    return number


def _positive(ctx: _Context, field: str, value: Any, what: str, bounds: tuple[float, float]) -> float:
    """A number within `bounds` (both > 0)."""
    lo, hi = bounds
    allowed = f"{what} from {lo:g} to {hi:g}"
    number = _number(ctx, field, value, allowed)
    if number <= 0:
        raise ctx.error(field, f"{number:g} is not positive", allowed)
    if not lo <= number <= hi:
        raise ctx.error(field, f"{number:g} is out of range", allowed)
    return number


def _vector3(ctx: _Context, field: str, value: Any, what: str, limit: float) -> NDArray[np.float64]:
    allowed = f"{what}: a list of 3 numbers, each from {-limit:g} to {limit:g}"
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 3:
        raise ctx.error(field, f"{_describe(value)} is not a list of 3 numbers", allowed)
    return np.array([_limited(ctx, f"{field}[{k}]", v, allowed, limit) for k, v in enumerate(value)])


def _limited(ctx: _Context, field: str, value: Any, allowed: str, limit: float) -> float:
    number = _number(ctx, field, value, allowed)
    if abs(number) > limit:
        raise ctx.error(field, f"{number:g} is out of range", allowed)
    return number


def _matrix4(ctx: _Context, field: str, value: Any) -> NDArray[np.float64]:
    allowed = (
        f"a 4x4 homogeneous transform as 4 rows of 4 numbers (row-major), each from {-LENGTH_LIMIT_M:g} "
        f"to {LENGTH_LIMIT_M:g}"
    )
    rows_ok = isinstance(value, Sequence) and not isinstance(value, str) and len(value) == 4
    if not rows_ok or not all(
        isinstance(r, Sequence) and not isinstance(r, str) and len(r) == 4 for r in value
    ):
        raise ctx.error(field, f"{_describe(value)} is not 4 rows of 4 numbers", allowed)
    return np.array(
        [
            [_limited(ctx, f"{field}[{r}][{k}]", v, allowed, LENGTH_LIMIT_M) for k, v in enumerate(row)]
            for r, row in enumerate(value)
        ]
    )


def _mapping(ctx: _Context, field: str, value: Any, keys: Sequence[str], what: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ctx.error(field, f"{_describe(value)} is not a mapping", f"{what} with keys {', '.join(keys)}")
    unknown = [str(k) for k in value if k not in keys]
    if unknown:
        dot = "." if field else ""
        raise ctx.error(f"{field}{dot}{unknown[0]}", "unknown key", f"{what} keys are {', '.join(keys)}")
    return value


def _joint_pose(ctx: _Context, field: str, joint: Mapping[str, Any], number: int) -> NDArray[np.float64]:
    has_transform = "transform" in joint
    has_xyz, has_rpy = "xyz" in joint, "rpy" in joint
    allowed = "either `transform` (4x4) or `xyz` + `rpy`, not both"
    if has_transform and (has_xyz or has_rpy):
        raise ctx.error(field, f"joint {number} gives both `transform` and `xyz`/`rpy`", allowed)
    if not has_transform and not (has_xyz or has_rpy):
        raise ctx.error(field, f"joint {number} gives no pose", allowed)
    if has_transform:
        matrix = _matrix4(ctx, f"{field}.transform", joint["transform"])
        try:
            return check_rigid_motion(matrix)
        except ValueError as exc:
            raise ctx.error(
                f"{field}.transform",
                f"joint {number}: not a rigid motion: {exc}",
                "an orthonormal rotation block with det +1 (to 1e-6) and bottom row [0, 0, 0, 1]",
            ) from None
    if not (has_xyz and has_rpy):
        missing = "rpy" if has_xyz else "xyz"
        raise ctx.error(f"{field}.{missing}", f"joint {number}: missing (xyz and rpy go together)", allowed)
    xyz = _vector3(ctx, f"{field}.xyz", joint["xyz"], "translation [m]", LENGTH_LIMIT_M)
    rpy = _vector3(ctx, f"{field}.rpy", joint["rpy"], "roll, pitch, yaw [rad]", ANGLE_LIMIT_RAD)
    return pose_from_xyz_rpy(xyz, rpy)


def _joint_capacity(ctx: _Context, field: str, joint: Mapping[str, Any], number: int) -> CapacitySource:
    allowed = "`capacity_nm`, or `radius_m` + `mu_delta0_pa` (+ optional `constant`)"
    direct = "capacity_nm" in joint
    physical = [k for k in ("radius_m", "mu_delta0_pa", "constant") if k in joint]
    if direct and physical:
        raise ctx.error(field, f"joint {number} gives both `capacity_nm` and `{physical[0]}`", allowed)
    if direct:
        capacity = _positive(
            ctx, f"{field}.capacity_nm", joint["capacity_nm"], "capacity [N·m]", CAPACITY_RANGE_NM
        )
        return CapacitySource(joint=number, kind="capacity_nm", capacity_nm=capacity)
    for key in ("radius_m", "mu_delta0_pa"):
        if key not in joint:
            raise ctx.error(f"{field}.{key}", f"joint {number}: missing (no capacity given)", allowed)
    radius = _positive(ctx, f"{field}.radius_m", joint["radius_m"], "ball radius [m]", RADIUS_RANGE_M)
    mu_delta0 = _positive(
        ctx, f"{field}.mu_delta0_pa", joint["mu_delta0_pa"], "mu_s*delta0 [Pa]", MU_DELTA0_RANGE_PA
    )
    spec = joint.get("constant", "paper")
    lo, hi = CONSTANT_RANGE
    try:
        constant = resolve_constant(spec)
    except (ValueError, OverflowError):
        raise ctx.error(
            f"{field}.constant",
            f"{_describe(spec)} is not a capacity constant",
            f"paper, derived or a number from {lo:g} to {hi:g}",
        ) from None
    if not lo <= constant.value <= hi:
        raise ctx.error(
            f"{field}.constant",
            f"{constant.value:g} is out of range",
            f"paper, derived or a number from {lo:g} to {hi:g}",
        )
    capacity = float(joint_capacity_nm(mu_delta0, radius, constant))
    lo, hi = CAPACITY_RANGE_NM
    if not lo <= capacity <= hi:
        raise ctx.error(
            field,
            f"joint {number}: c·μs·δ0·R³ = {capacity:.3g} N·m is out of range",
            f"a capacity from {lo:g} to {hi:g} N·m",
        )
    return CapacitySource(
        joint=number,
        kind="radius_mu_delta0",
        capacity_nm=capacity,
        radius_m=radius,
        mu_delta0_pa=mu_delta0,
        constant=constant,
    )


def parse_link(data: Mapping[str, Any] | Any, source: str, *, field_prefix: str = "") -> LinkSpec:
    """Validate a parsed link mapping (docs/formats.md §3) into a `LinkSpec`.

    `source` names the file in error messages; `field_prefix` (e.g. 'article.') is put before
    every field path when the link is a section of a larger file.
    """
    ctx = _Context(source, field_prefix)
    top = _mapping(ctx, "", data, _TOP_KEYS, "a link")
    for key in ("joints", "load"):
        if key not in top:
            raise ctx.error(key, "missing", "a link has `joints` (list, base to tip) and `load`")

    g = PAPER_G_M_S2 if "g" not in top else _positive(ctx, "g", top["g"], "gravity [m/s²]", G_RANGE)

    joints = top["joints"]
    if not isinstance(joints, Sequence) or isinstance(joints, str) or not 0 < len(joints) <= MAX_JOINTS:
        raise ctx.error(
            "joints",
            f"{_describe(joints)} is not a non-empty list of at most {MAX_JOINTS}",
            "a list of joints, base to tip",
        )
    transforms = []
    sources = []
    for index, raw in enumerate(joints):
        field = f"joints[{index}]"
        joint = _mapping(ctx, field, raw, _JOINT_KEYS, f"joint {index + 1}")
        transforms.append(_joint_pose(ctx, field, joint, index + 1))
        sources.append(_joint_capacity(ctx, field, joint, index + 1))

    load = _mapping(ctx, "load", top["load"], _LOAD_KEYS, "the load")
    if "point_m" not in load:
        raise ctx.error("load.point_m", "missing", "the acting point Q in the tip frame [m], 3 numbers")
    point = _vector3(
        ctx, "load.point_m", load["point_m"], "acting point in the tip frame [m]", LENGTH_LIMIT_M
    )
    load_allowed = (
        f"exactly one of `direction` (base frame) or `force_n` [N], of length >= {MIN_VECTOR_NORM:g}"
    )
    if ("direction" in load) == ("force_n" in load):
        both = "both" if "direction" in load else "neither"
        raise ctx.error("load", f"gives {both} of `direction` and `force_n`", load_allowed)
    key = "direction" if "direction" in load else "force_n"
    limit = DIRECTION_LIMIT if key == "direction" else FORCE_LIMIT_N
    vector = _vector3(ctx, f"load.{key}", load[key], "a non-zero vector in the base frame", limit)
    norm = float(np.linalg.norm(vector))
    if norm == 0:
        raise ctx.error(f"load.{key}", "is the zero vector", load_allowed)
    if norm < MIN_VECTOR_NORM:
        raise ctx.error(f"load.{key}", f"is too short ({norm:.3g})", load_allowed)
    force = vector if key == "force_n" else None

    transforms_array = np.stack(transforms)
    capacities = np.array([s.capacity_nm for s in sources])
    direction = vector / norm
    for array in (transforms_array, capacities, point, direction):
        array.setflags(write=False)
    if force is not None:
        force.setflags(write=False)
    return LinkSpec(
        source=source,
        transforms=transforms_array,
        capacities_nm=capacities,
        capacity_sources=tuple(sources),
        point_m=point,
        direction_w=direction,
        force_n=force,
        g=g,
    )


def load_link_file(path: str | os.PathLike[str]) -> LinkSpec:
    """Read and validate a link file; every problem is an `InputError` naming the file and field."""
    return parse_link(load_yaml_file(path, what="a link YAML file"), str(path))
