"""The joint-estimation fit `m_s = k / l_s` (docs/model.md §4) and the joint capacity it implies.

One-parameter least squares through the origin in x = 1/l, with MATLAB `cftool` conventions:
`k̂ = Σxm / Σx²`, `SSE = Σ(m − k̂x)²`, `SST = Σ(m − m̄)²`, `R² = 1 − SSE/SST`, `dfe = n − 1`,
`RMSE = √(SSE/dfe)`, `se = RMSE/√Σx²`, bounds `k̂ ± t_{(1+level)/2, n−1} · se` (MATLAB `confint`).

Numerics. Every statistic is a rational function of five sums of the data (n, Σx², Σxm, Σm², Σm),
and `SSE = Σm² − (Σxm)²/Σx²` and `SST = Σm² − (Σm)²/n` cancel catastrophically in floating point
when R² → 1 or when the masses barely vary. So the sums are kept **exactly**: every finite double
is an integer multiple of 2^-1074, so `v·2^1074` is a Python int and the sums of products are ints
scaled by 2^2148, with no rounding at all. k̂, SSE, SST and R² are then each the exact rational value
rounded once (Python's int/int division is correctly rounded); RMSE and se add one `sqrt` rounding.
The batch fit here and the online fit (`model.online_fit`) share these exact sums and this one
evaluator, so the online estimate after every update is the batch fit of the data so far, bit for bit.
The only rounding the two cannot remove is x = 1/l itself, done identically (IEEE division) in both.

R² when SST = 0 (all masses equal): R² is undefined (MATLAB's `1 − SSE/0` gives NaN or −Inf);
this module returns NaN and does not raise, because k̂, SSE, RMSE and the bounds are still well
defined and an online fit may legitimately see two equal masses first. JSON shows it as null.
R² can be negative: a fit through the origin can be worse than the constant mean (as in MATLAB).

Degenerate fits. The numbers above stay MATLAB's whatever the data; `degenerate_reasons` says when
they describe nothing about the law m = k/l (every slip at one distance, or masses that do not fall
with distance: R² < 0), and `nonnegative_bounds` is how bounds on k, the capacity or μs·δ0 are shown:
the t interval intersected with [0, ∞), since none of them can be negative (the intersection keeps
the interval's coverage, the true value being in [0, ∞)). docs/model.md §4, "Degenerate fits".
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike

from model.gravity import PAPER_G_M_S2
from model.joint import CapacityConstant, mu_delta0_pa_from_capacity, resolve_constant

DEFAULT_LEVEL: Final[float] = 0.99
DEFAULT_G: Final[float] = PAPER_G_M_S2  # the fit's default g: the paper's

# Every finite double is an integer multiple of 2**-1074 (the smallest subnormal).
_SCALE_BITS: Final[int] = 1074
_SCALE_SQUARED: Final[int] = 1 << (2 * _SCALE_BITS)


@dataclass(frozen=True)
class InverseFit:
    """Result of fitting `m = k / l` through the origin (MATLAB cftool conventions, docs/model.md §4).

    Attributes:
        n: number of (distance, mass) pairs.
        k: fitted coefficient [kg·m]; the joint capacity is k·g.
        k_ci: (lower, upper) confidence bounds on k [kg·m] at `level`.
        sse: residual sum of squares [kg²].
        sst: total sum of squares about the mean mass [kg²].
        r2: 1 − SSE/SST; NaN when SST = 0 (all masses equal); may be negative.
        rmse: √(SSE/dfe) [kg].
        dfe: residual degrees of freedom, n − 1 (one parameter, no offset).
        se: standard error of k [kg·m].
        t: the Student-t quantile t_{(1+level)/2, dfe} used for the bounds.
        level: confidence level of the bounds, in (0, 1).
    """

    n: int
    k: float
    k_ci: tuple[float, float]
    sse: float
    sst: float
    r2: float
    rmse: float
    dfe: int
    se: float
    t: float
    level: float


@dataclass(frozen=True)
class ExactSums:
    """The sufficient statistics of the fit, held exactly (see the module docstring).

    `sum_x2`, `sum_xm`, `sum_m2` are Σx², Σxm, Σm² times 2^2148; `sum_m` is Σm times 2^1074.
    """

    n: int = 0
    sum_x2: int = 0
    sum_xm: int = 0
    sum_m2: int = 0
    sum_m: int = 0

    def add(self, inverse_distance: float, mass: float) -> ExactSums:
        """These sums with one more pair (x = 1/l, m) added, exactly."""
        x = scaled_int(inverse_distance)
        m = scaled_int(mass)
        return ExactSums(
            n=self.n + 1,
            sum_x2=self.sum_x2 + x * x,
            sum_xm=self.sum_xm + x * m,
            sum_m2=self.sum_m2 + m * m,
            sum_m=self.sum_m + m,
        )


def scaled_int(value: float) -> int:
    """`value · 2^1074` as an exact int (any finite double is a multiple of 2^-1074)."""
    numerator, denominator = float(value).as_integer_ratio()
    # The denominator is a power of two no larger than 2**1074.
    return numerator << (_SCALE_BITS - (denominator.bit_length() - 1))


def check_level(level: float) -> float:
    """Return `level` as a float if it is in the open interval (0, 1); else raise ValueError."""
    try:
        value = float(level)
    except (TypeError, ValueError):
        raise ValueError(f"level {level!r}: allowed: a number in the open interval (0, 1)") from None
    if not (0.0 < value < 1.0):
        raise ValueError(f"level {level!r}: allowed: a number in the open interval (0, 1), e.g. 0.99")
    return value


def check_pair(distance_m: float, mass_kg: float, where: str = "") -> tuple[float, float]:
    """Validate one (distance, mass) pair; return it as floats. `where` prefixes the error message."""
    prefix = f"{where}: " if where else ""
    try:
        distance = float(distance_m)
        mass = float(mass_kg)
    except (TypeError, ValueError):
        raise ValueError(f"{prefix}distance {distance_m!r} / mass {mass_kg!r}: allowed: numbers") from None
    if not math.isfinite(distance) or distance <= 0.0:
        raise ValueError(f"{prefix}distance_m = {distance!r}; allowed: finite and > 0 m")
    if not math.isfinite(mass):
        raise ValueError(f"{prefix}mass_kg = {mass!r}; allowed: finite")
    return distance, mass


@lru_cache(maxsize=4096)
def t_quantile(level: float, dfe: int) -> float:
    """Two-sided Student-t quantile t_{(1+level)/2, dfe}, as MATLAB `confint` uses."""
    from scipy import stats  # imported on first use: it costs ~1 s, and `rig --help` needs none of it

    return float(stats.t.ppf(0.5 * (1.0 + level), dfe))


def _ratio(numerator: int, denominator: int) -> float:
    """Correctly rounded numerator/denominator, with a clear error if it leaves the float range."""
    try:
        return numerator / denominator
    except OverflowError:
        raise ValueError("fit statistics overflow the float range; rescale the data") from None


def fit_from_sums(sums: ExactSums, level: float = DEFAULT_LEVEL) -> InverseFit:
    """Evaluate every fit statistic from exact sums (shared by the batch and the online fit)."""
    level = check_level(level)
    n = sums.n
    if n < 2:
        raise ValueError(f"{n} data point(s); allowed: at least 2 (distance, mass) pairs for a fit")
    a, b, c, d = sums.sum_x2, sums.sum_xm, sums.sum_m2, sums.sum_m
    # a > 0: every x = 1/l is > 0 (a subnormal x still has a nonzero exact square).
    k = _ratio(b, a)
    sse_numerator = max(c * a - b * b, 0)  # Cauchy-Schwarz: exactly >= 0; max() only documents it
    sse = _ratio(sse_numerator, a * _SCALE_SQUARED)
    sst_numerator = n * c - d * d
    sst = _ratio(sst_numerator, n * _SCALE_SQUARED)
    # R² = 1 − SSE/SST as one exact fraction, rounded once (exact even when R² is near 0 or 1).
    r2 = math.nan if sst_numerator == 0 else _ratio(a * sst_numerator - n * sse_numerator, a * sst_numerator)
    dfe = n - 1
    rmse = math.sqrt(_ratio(sse_numerator, a * _SCALE_SQUARED * dfe))
    se = math.sqrt(_ratio(sse_numerator, a * a * dfe))
    t = t_quantile(level, dfe)
    half_width = t * se
    return InverseFit(
        n=n,
        k=k,
        k_ci=(k - half_width, k + half_width),
        sse=sse,
        sst=sst,
        r2=r2,
        rmse=rmse,
        dfe=dfe,
        se=se,
        t=t,
        level=level,
    )


def _as_float_list(name: str, values: ArrayLike) -> list[float]:
    array = np.asarray(values, dtype=float)
    if array.ndim != 1:
        raise ValueError(f"{name}: shape {array.shape}; allowed: a one-dimensional sequence")
    return [float(v) for v in array]


def fit_inverse_distance(
    distances_m: ArrayLike, masses_kg: ArrayLike, level: float = DEFAULT_LEVEL
) -> InverseFit:
    """Fit `m = k / l` to slip masses `masses_kg` [kg] at distances `distances_m` [m].

    Raises ValueError for fewer than 2 points, unequal lengths, a distance <= 0, a non-finite value
    or a level outside (0, 1). All-equal masses are allowed (R² is NaN, see the module docstring).
    """
    level = check_level(level)
    distances = _as_float_list("distances_m", distances_m)
    masses = _as_float_list("masses_kg", masses_kg)
    if len(distances) != len(masses):
        raise ValueError(
            f"{len(distances)} distances but {len(masses)} masses; allowed: one mass per distance"
        )
    sums = ExactSums()
    for index, (distance, mass) in enumerate(zip(distances, masses, strict=True), start=1):
        distance, mass = check_pair(distance, mass, where=f"point {index}")
        sums = sums.add(1.0 / distance, mass)
    return fit_from_sums(sums, level)


@dataclass(frozen=True)
class CapacityEstimate:
    """The joint capacity and μs·δ0 implied by a fit (docs/model.md §4): capacity = k·g, μs·δ0 = k·g/(c·R³).

    Attributes:
        constant: name of the constant c ('paper', 'derived' or 'custom').
        c: its value.
        radius_m: ball radius R [m].
        g: gravitational acceleration used [m/s²].
        mu_delta0_pa: μs·δ0 [Pa]; depends on c.
        mu_delta0_ci_pa: its bounds [Pa] (the bounds on k, scaled).
        capacity_nm: joint load-bearing capacity N_max = k·g [N·m]; independent of c.
        capacity_ci_nm: its bounds [N·m].
        capacity_se_nm: standard error of the capacity, se(k)·g [N·m].
        level: confidence level of the bounds.
    """

    constant: str
    c: float
    radius_m: float
    g: float
    mu_delta0_pa: float
    mu_delta0_ci_pa: tuple[float, float]
    capacity_nm: float
    capacity_ci_nm: tuple[float, float]
    capacity_se_nm: float
    level: float


def capacity_from_fit(
    fit: InverseFit,
    radius_m: float,
    constant: str | float | CapacityConstant = "paper",
    g: float = DEFAULT_G,
) -> CapacityEstimate:
    """Joint capacity and μs·δ0 (with bounds) from a fit, a ball radius and the constant c.

    Raises ValueError for a radius or g that is not finite and > 0, or an unknown constant.
    """
    resolved = resolve_constant(constant)
    radius = float(radius_m)
    if not (math.isfinite(radius) and radius > 0.0):
        raise ValueError(f"radius_m = {radius_m!r}; allowed: finite and > 0 m")
    g_value = float(g)
    if not (math.isfinite(g_value) and g_value > 0.0):
        raise ValueError(f"g = {g!r}; allowed: finite and > 0 m/s^2")
    capacity = fit.k * g_value
    capacity_ci = (fit.k_ci[0] * g_value, fit.k_ci[1] * g_value)
    # Bounds may be negative for a very uncertain fit, so scale by μs·δ0 per N·m instead of
    # passing them through the inverse (which only accepts capacities >= 0).
    pa_per_nm = float(mu_delta0_pa_from_capacity(1.0, radius, resolved))
    return CapacityEstimate(
        constant=resolved.name,
        c=resolved.value,
        radius_m=radius,
        g=g_value,
        mu_delta0_pa=capacity * pa_per_nm,
        mu_delta0_ci_pa=(capacity_ci[0] * pa_per_nm, capacity_ci[1] * pa_per_nm),
        capacity_nm=capacity,
        capacity_ci_nm=capacity_ci,
        capacity_se_nm=fit.se * g_value,
        level=fit.level,
    )


@dataclass(frozen=True, slots=True)
class FitSummary:
    """A joint-estimation fit with the capacity it implies: the `rig fit --json` object (docs/formats.md §4).

    Field order is the JSON contract's key order. Floats may be NaN where a statistic is undefined
    (R² when SST = 0); JSON shows those as null.
    """

    n: int
    k: float
    k_ci: tuple[float, float]
    sse: float
    sst: float
    r2: float
    rmse: float
    dfe: int
    se: float
    level: float
    constant: str
    c: float
    radius_m: float
    mu_delta0_pa: float
    mu_delta0_ci_pa: tuple[float, float]
    capacity_nm: float
    capacity_ci_nm: tuple[float, float]

    def as_json(self) -> dict[str, Any]:
        """The `rig fit --json` object: keys in contract order, plain Python values, pairs as lists."""
        return {
            name: list(value) if isinstance(value, tuple) else value
            for name, value in ((f.name, getattr(self, f.name)) for f in fields(self))
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> FitSummary:
        """Read a `rig fit --json` object back (null numbers become NaN); KeyError names a missing key."""
        values: dict[str, Any] = {}
        for f in fields(cls):
            raw = data[f.name]
            if f.name in ("n", "dfe"):
                values[f.name] = int(raw)
            elif f.name == "constant":
                values[f.name] = str(raw)
            elif f.name.endswith("_ci") or "_ci_" in f.name:
                lo, hi = raw
                values[f.name] = (_float_or_nan(lo), _float_or_nan(hi))
            else:
                values[f.name] = _float_or_nan(raw)
        return cls(**values)


def _float_or_nan(value: Any) -> float:
    return math.nan if value is None else float(value)


SUMMARY_KEYS: Final[tuple[str, ...]] = tuple(f.name for f in fields(FitSummary))


def fit_summary(fit: InverseFit, capacity: CapacityEstimate) -> FitSummary:
    """The fit and its capacity as one `FitSummary` of plain Python values."""
    return FitSummary(
        n=int(fit.n),
        k=float(fit.k),
        k_ci=_plain_pair(fit.k_ci),
        sse=float(fit.sse),
        sst=float(fit.sst),
        r2=float(fit.r2),
        rmse=float(fit.rmse),
        dfe=int(fit.dfe),
        se=float(fit.se),
        level=float(fit.level),
        constant=capacity.constant,
        c=float(capacity.c),
        radius_m=float(capacity.radius_m),
        mu_delta0_pa=float(capacity.mu_delta0_pa),
        mu_delta0_ci_pa=_plain_pair(capacity.mu_delta0_ci_pa),
        capacity_nm=float(capacity.capacity_nm),
        capacity_ci_nm=_plain_pair(capacity.capacity_ci_nm),
    )


def _plain_pair(pair: Iterable[float]) -> tuple[float, float]:
    lo, hi = pair
    return float(lo), float(hi)


def degenerate_reasons(slip_distances_m: Iterable[float], fit: FitSummary) -> tuple[str, ...]:
    """Why a fit of the slips at `slip_distances_m` says nothing about m = k/l (empty: a sound fit).

    `fit` is the paper's fit of those slips (its R² is cftool's, about the mean mass).
    """
    distinct = sorted(set(slip_distances_m))
    if len(distinct) == 1:
        return (
            f"every slip is at one distance ({distinct[0]:g} m): the fit cannot test m = k/l, k is only "
            "the mean of m·l and R² is 0 (or undefined) by construction; hang the load at several distances",
        )
    if fit.k <= 0.0:
        return ("every slip mass is 0: there is no load to fit",)
    if fit.r2 < 0.0 or (math.isnan(fit.r2) and fit.sse > 0.0):
        return (
            "the slip masses do not fall with distance as 1/l: a constant mass fits them better than k/l "
            f"(R² {'undefined, all masses equal' if math.isnan(fit.r2) else f'{fit.r2:.3g} < 0'}); check the "
            "distances and that the joint under test is the one that slipped",
        )
    return ()


def nonnegative_bounds(bounds: tuple[float, float]) -> tuple[float, float]:
    """Bounds on a quantity that cannot be negative (k, a capacity, μs·δ0): the interval ∩ [0, ∞)."""
    lo, hi = bounds
    return max(lo, 0.0), max(hi, 0.0)
