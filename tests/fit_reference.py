"""Shared test helpers for the fit: an exact rational reference and a strategy for nasty data sets."""

import math
from fractions import Fraction

import pytest
from hypothesis import strategies as st

VECTOR9_DISTANCES_M = [0.1, 0.2, 0.4, 0.5]
VECTOR9_MASSES_KG = [1.7, 0.78, 0.41, 0.33]


def exact_reference(distances_m, masses_kg):
    """Every statistic in exact rational arithmetic, by the residual definitions (not by the sums)."""
    x = [Fraction(1.0 / float(d)) for d in distances_m]
    m = [Fraction(float(v)) for v in masses_kg]
    n = len(m)
    k = sum(a * b for a, b in zip(x, m, strict=True)) / sum(a * a for a in x)
    sse = sum((b - k * a) ** 2 for a, b in zip(x, m, strict=True))
    mean = sum(m) / n
    sst = sum((b - mean) ** 2 for b in m)
    return {
        "k": k,
        "sse": sse,
        "sst": sst,
        "r2": (1 - sse / sst) if sst else None,
        "rmse2": sse / (n - 1),
        "se2": sse / ((n - 1) * sum(a * a for a in x)),
    }


def assert_matches_exact(fit, ref, rel=1e-12):
    assert fit.k == pytest.approx(float(ref["k"]), rel=rel, abs=0)
    assert fit.sse == pytest.approx(float(ref["sse"]), rel=rel, abs=0)
    assert fit.sst == pytest.approx(float(ref["sst"]), rel=rel, abs=0)
    if ref["r2"] is None:
        assert math.isnan(fit.r2)
    else:
        assert fit.r2 == pytest.approx(float(ref["r2"]), rel=rel, abs=0)
    assert fit.rmse == pytest.approx(math.sqrt(float(ref["rmse2"])), rel=rel, abs=0)
    assert fit.se == pytest.approx(math.sqrt(float(ref["se2"])), rel=rel, abs=0)
    # The bounds k ± t·se round once relative to the terms added, not to their (possibly ~0) sum.
    scale = abs(fit.k) + fit.t * fit.se
    assert fit.k_ci[0] == pytest.approx(float(ref["k"]) - fit.t * fit.se, abs=rel * scale)
    assert fit.k_ci[1] == pytest.approx(float(ref["k"]) + fit.t * fit.se, abs=rel * scale)


def _scaled(values, exponent):
    return [v * 10.0**exponent for v in values]


@st.composite
def nasty_data(draw):
    """Data sets that break naive formulas: R² → 1, tiny spread, extreme scales, exact fits, repeats."""
    n = draw(st.integers(2, 12))
    distance_exp = draw(st.integers(-40, 40))
    mass_exp = draw(st.integers(-40, 40))
    base = draw(st.lists(st.floats(0.01, 1.0), min_size=n, max_size=n))
    distances = _scaled(base, distance_exp)
    kind = draw(st.sampled_from(["near_perfect", "exact", "tiny_spread", "equal", "general", "repeats"]))
    k = draw(st.floats(0.05, 5.0))
    if kind == "near_perfect":
        rel_noise = 10.0 ** draw(st.integers(-15, -3))
        eps = draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n))
        masses = [k / b * (1 + rel_noise * e) for b, e in zip(base, eps, strict=True)]
    elif kind == "exact":
        masses = [k / b for b in base]
    elif kind == "tiny_spread":
        spread = 10.0 ** draw(st.integers(-14, -4))
        eps = draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n))
        masses = [k * (1 + spread * e) for e in eps]
    elif kind == "equal":
        masses = [k] * n
    elif kind == "repeats":
        distances = [distances[0]] * n
        masses = [k * (1 + 0.01 * i) for i in range(n)]
    else:
        masses = draw(st.lists(st.floats(-10, 10), min_size=n, max_size=n))
    return distances, _scaled(masses, mass_exp)
