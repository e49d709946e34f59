"""Statics of one preloaded spherical joint (docs/model.md §2): capacity, contact solution, stress quadrature.

The ball of radius R sits in a socket that touches it over the whole sphere. The contact carries a
normal stress `σ(n) = δ0 + δmax (n·e)` and a friction stress `μ σ` along `t = (n × m̂)/|n × m̂|`,
where m̂ is the axis of the applied moment. The joint slips when the friction coefficient needed
for equilibrium exceeds μs, so its capacity is `N_max = c · μs·δ0 · R³`.

The constant c is a named setting (`CapacityConstant`): `paper` (5.4397, printed by the paper) or
`derived` (π², what the sphere integrals give). Every result that depends on c carries the
`CapacityConstant` it used. SI units throughout; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

PAPER_CONSTANT: Final[float] = 5.4397
DERIVED_CONSTANT: Final[float] = math.pi**2

_NAMED_CONSTANTS: Final[dict[str, float]] = {"paper": PAPER_CONSTANT, "derived": DERIVED_CONSTANT}
_ALLOWED_CONSTANTS: Final[str] = "'paper' (5.4397), 'derived' (pi**2) or a positive finite number"


@dataclass(frozen=True)
class CapacityConstant:
    """The constant c in `N_max = c · μs·δ0 · R³`, with the name it was chosen by."""

    name: str
    value: float

    def __post_init__(self) -> None:
        """Reject a non-positive or non-finite value."""
        if not (isinstance(self.value, int | float) and math.isfinite(self.value) and self.value > 0):
            raise ValueError(f"capacity constant value {self.value!r}: allowed {_ALLOWED_CONSTANTS}")


def resolve_constant(spec: str | float | CapacityConstant = "paper") -> CapacityConstant:
    """Turn 'paper', 'derived', a positive finite number or a `CapacityConstant` into a `CapacityConstant`.

    A bare number is named 'custom'. Anything else raises `ValueError` naming what is allowed.
    """
    if isinstance(spec, CapacityConstant):
        return spec
    if isinstance(spec, str):
        key = spec.strip().lower()
        if key in _NAMED_CONSTANTS:
            return CapacityConstant(key, _NAMED_CONSTANTS[key])
        raise ValueError(f"unknown capacity constant {spec!r}; allowed: {_ALLOWED_CONSTANTS}")
    if isinstance(spec, bool) or not isinstance(spec, int | float | np.integer | np.floating):
        raise ValueError(
            f"capacity constant {spec!r} of type {type(spec).__name__}; allowed: {_ALLOWED_CONSTANTS}"
        )
    value = float(spec)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"capacity constant {value!r}; allowed: {_ALLOWED_CONSTANTS}")
    return CapacityConstant("custom", value)


def _positive_array(name: str, value: ArrayLike, *, allow_zero: bool) -> NDArray[np.float64]:
    array = np.asarray(value, dtype=float)
    bad = ~np.isfinite(array) | ((array < 0) if allow_zero else (array <= 0))
    if np.any(bad):
        first = array[bad].flat[0] if array.ndim else float(array)
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} = {first!r}; allowed: finite and {bound}")
    return array


def _scalar_or_array(array: NDArray[np.float64]) -> float | NDArray[np.float64]:
    return float(array) if array.ndim == 0 else array


def joint_capacity_nm(
    mu_delta0_pa: ArrayLike, radius_m: ArrayLike, constant: str | float | CapacityConstant = "paper"
) -> float | NDArray[np.float64]:
    """Load-bearing capacity `c · μs·δ0 · R³` [N·m] (Lemma 1); broadcasts over arrays."""
    c = resolve_constant(constant).value
    mu_delta0 = _positive_array("mu_delta0_pa", mu_delta0_pa, allow_zero=True)
    radius = _positive_array("radius_m", radius_m, allow_zero=False)
    return _scalar_or_array(c * mu_delta0 * radius**3)


def mu_delta0_pa_from_capacity(
    capacity_nm: ArrayLike, radius_m: ArrayLike, constant: str | float | CapacityConstant = "paper"
) -> float | NDArray[np.float64]:
    """Inverse of `joint_capacity_nm`: `μs·δ0 = N_max / (c R³)` [Pa]; broadcasts over arrays."""
    c = resolve_constant(constant).value
    capacity = _positive_array("capacity_nm", capacity_nm, allow_zero=True)
    radius = _positive_array("radius_m", radius_m, allow_zero=False)
    return _scalar_or_array(capacity / (c * radius**3))


@dataclass(frozen=True)
class ContactSolution:
    """Equilibrium of one joint under a force at a point (docs/model.md §2), in the joint's own frame.

    `contact_frame` is a rotation whose columns are the solution axes written in the input frame:
    x along the force, y along the applied moment Q × F (the friction axis), z = x × y. In that
    frame the load is the paper's representative case F = (f, 0, 0) at Q = (0, 0, l), and
    `e = (cos θ, 0, sin θ)` is the direction of the peak extra normal stress `delta_max_pa`.
    `mu` is the friction coefficient equilibrium needs; the joint holds while `mu <= μs`, i.e. while
    `moment_nm <= joint_capacity_nm(μs·δ0, R, constant)`. `compressive` says δmax <= δ0 (the
    linearised contact never pulls). `constant` is the c used for `mu`.
    """

    mu: float
    theta_rad: float
    delta_max_pa: float
    delta0_pa: float
    radius_m: float
    force_n: float
    lever_arm_m: float
    moment_nm: float
    compressive: bool
    constant: CapacityConstant
    contact_frame: NDArray[np.float64]


def _unit_perpendicular(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """A unit vector orthogonal to unit vector v (deterministic)."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(v[1]) < 0.9 else np.array([0.0, 0.0, 1.0])
    w = np.cross(helper, v)
    unit: NDArray[np.float64] = w / np.linalg.norm(w)
    return unit


def _three_vector(name: str, value: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(value, dtype=float)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{name} = {value!r}; allowed: three finite numbers")
    return array


def solve_contact(
    force_n: ArrayLike,
    point_m: ArrayLike,
    radius_m: float,
    delta0_pa: float,
    constant: str | float | CapacityConstant = "paper",
) -> ContactSolution:
    """Solve the joint's contact for force `force_n` (3,) acting at `point_m` (3,) from the ball centre.

    Any force at any point reduces to f = |F| and l = |Q × F| / |F| (docs/model.md §2). Then
    `μ = f l / (c δ0 R³)`, `θ = atan(3πμ/8)`, `δmax = 3 f cos θ / (4π R²)`.
    """
    c = resolve_constant(constant)
    force = _three_vector("force_n", force_n)
    point = _three_vector("point_m", point_m)
    radius = float(_positive_array("radius_m", radius_m, allow_zero=False))
    delta0 = float(_positive_array("delta0_pa", delta0_pa, allow_zero=False))

    f = float(np.linalg.norm(force))
    moment = np.cross(point, force)
    moment_nm = float(np.linalg.norm(moment))
    lever_arm_m = moment_nm / f if f > 0 else 0.0

    x_axis = force / f if f > 0 else np.array([1.0, 0.0, 0.0])
    # On the force's line of action the moment axis is undefined; any axis across the force serves.
    y_axis = moment / moment_nm if moment_nm > 0 else _unit_perpendicular(x_axis)
    y_axis = y_axis - x_axis * float(x_axis @ y_axis)
    y_axis /= np.linalg.norm(y_axis)
    frame = np.column_stack([x_axis, y_axis, np.cross(x_axis, y_axis)])
    frame.setflags(write=False)

    mu = moment_nm / (c.value * delta0 * radius**3)
    theta = math.atan(3.0 * math.pi * mu / 8.0)
    delta_max = 3.0 * f * math.cos(theta) / (4.0 * math.pi * radius**2)
    return ContactSolution(
        mu=mu,
        theta_rad=theta,
        delta_max_pa=delta_max,
        delta0_pa=delta0,
        radius_m=radius,
        force_n=f,
        lever_arm_m=lever_arm_m,
        moment_nm=moment_nm,
        compressive=delta_max <= delta0,
        constant=c,
        contact_frame=frame,
    )


@dataclass(frozen=True)
class ContactWrench:
    """Resultant of the contact stresses on the ball: force [N] and moment about its centre [N·m]."""

    force_n: NDArray[np.float64]
    moment_nm: NDArray[np.float64]


def contact_stresses(
    solution: ContactSolution, normals: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Normal stress σ [Pa] and unit friction direction t at outward unit normals `normals` (..., 3).

    Both in the solution's input frame. `t` is undefined on the moment axis; there it is returned as
    zero (a set of measure zero, never sampled by `contact_wrench`).
    """
    local = np.asarray(normals, dtype=float) @ solution.contact_frame  # rows: n in the contact frame
    e = np.array([math.cos(solution.theta_rad), 0.0, math.sin(solution.theta_rad)])
    sigma = solution.delta0_pa + solution.delta_max_pa * (local @ e)
    # n × ŷ = (-n_z, 0, n_x) in the contact frame.
    across = np.stack([-local[..., 2], np.zeros_like(local[..., 0]), local[..., 0]], axis=-1)
    rho = np.linalg.norm(across, axis=-1, keepdims=True)
    t_local = np.divide(across, rho, out=np.zeros_like(across), where=rho > 0)
    return sigma, t_local @ solution.contact_frame.T


def contact_wrench(solution: ContactSolution, n_polar: int = 48, n_azimuth: int = 48) -> ContactWrench:
    """Integrate the contact stresses over the sphere: the wrench the socket exerts on the ball.

    With the derived constant (c = π²) it balances the load: force = −F, moment = −Q × F.
    With another c the moment comes out scaled by π²/c (that is what c's choice means).

    Coordinates: polar angle ψ measured from the moment axis (where t is singular), azimuth φ
    around it. There `t = (−sin φ, 0, cos φ)` is smooth and every integrand, including the area
    element sin ψ, is a low-degree trigonometric polynomial in ψ and φ, so Gauss-Legendre in ψ and
    the trapezoid rule in φ converge spectrally (Gauss-Legendre in cos ψ would meet √(1−cos²ψ)
    factors and converge only algebraically).
    """
    if n_polar < 2 or n_azimuth < 3:
        raise ValueError(f"n_polar={n_polar}, n_azimuth={n_azimuth}; allowed: n_polar >= 2, n_azimuth >= 3")
    nodes, weights = np.polynomial.legendre.leggauss(n_polar)
    psi = 0.5 * math.pi * (nodes + 1.0)
    w_psi = 0.5 * math.pi * weights
    phi = 2.0 * math.pi * np.arange(n_azimuth) / n_azimuth
    w_phi = 2.0 * math.pi / n_azimuth
    psi_grid, phi_grid = np.meshgrid(psi, phi, indexing="ij")
    sin_psi = np.sin(psi_grid)
    # Normal in the contact frame: polar axis along y (the moment axis).
    local = np.stack([sin_psi * np.cos(phi_grid), np.cos(psi_grid), sin_psi * np.sin(phi_grid)], axis=-1)
    normals = local @ solution.contact_frame.T
    sigma, t = contact_stresses(solution, normals)
    r = solution.radius_m
    d_area = (r**2) * sin_psi * (w_psi[:, None] * w_phi)
    traction = (-sigma[..., None] * normals + solution.mu * sigma[..., None] * t) * d_area[..., None]
    force = traction.sum(axis=(0, 1))
    moment = np.cross(r * normals, traction).sum(axis=(0, 1))
    return ContactWrench(force_n=force, moment_nm=moment)
