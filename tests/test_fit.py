"""The batch fit m = k/l (docs/model.md §4): §8 values, an independent implementation, exactness, errors."""

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from model.fit import (
    SUMMARY_KEYS,
    capacity_from_fit,
    fit_inverse_distance,
    fit_summary,
)
from tests.fit_reference import (
    VECTOR9_DISTANCES_M,
    VECTOR9_MASSES_KG,
    assert_matches_exact,
    exact_reference,
    nasty_data,
)


def test_model_vector_9_every_statistic():
    fit = fit_inverse_distance(VECTOR9_DISTANCES_M, VECTOR9_MASSES_KG, level=0.99)
    assert fit.n == 4
    assert fit.dfe == 3
    assert fit.level == 0.99
    assert fit.k == pytest.approx(0.16698706, rel=1e-6)
    assert fit.sse == pytest.approx(0.00399723, rel=1e-6)
    assert fit.sst == pytest.approx(1.1833, rel=1e-6)
    assert fit.r2 == pytest.approx(0.99662197, rel=1e-6)
    assert fit.rmse == pytest.approx(0.03650218, rel=1e-6)
    assert fit.se == pytest.approx(0.00313870, rel=1e-6)
    assert fit.t == pytest.approx(5.8409093, rel=1e-6)
    assert fit.k_ci[0] == pytest.approx(0.14865418, rel=1e-6)
    assert fit.k_ci[1] == pytest.approx(0.18531994, rel=1e-6)


@pytest.mark.parametrize(
    ("k", "derived_pa", "paper_pa"),
    [(0.1615, 160361.04, 290953.55), (0.2627, 260847.33, 473272.42)],
    ids=["vector10-link1", "vector11-link2"],
)
def test_model_vectors_10_11_mu_delta0(k, derived_pa, paper_pa):
    base = fit_inverse_distance(VECTOR9_DISTANCES_M, VECTOR9_MASSES_KG)
    fit = dataclasses.replace(base, k=k, k_ci=(k - 0.01, k + 0.01))
    derived = capacity_from_fit(fit, radius_m=0.01, constant="derived")
    paper = capacity_from_fit(fit, radius_m=0.01, constant="paper")
    assert derived.mu_delta0_pa == pytest.approx(derived_pa, rel=1e-6)
    assert paper.mu_delta0_pa == pytest.approx(paper_pa, rel=1e-6)
    assert derived.constant == "derived" and paper.constant == "paper"
    # c cancels in the capacity: k·g whatever the constant.
    assert derived.capacity_nm == paper.capacity_nm == pytest.approx(k * 9.8, rel=1e-15)
    lo, hi = paper.mu_delta0_ci_pa
    assert lo == pytest.approx((k - 0.01) * 9.8 / (5.4397 * 1e-6), rel=1e-12)
    assert hi == pytest.approx((k + 0.01) * 9.8 / (5.4397 * 1e-6), rel=1e-12)


def test_paper_link_capacities_from_k():
    base = fit_inverse_distance(VECTOR9_DISTANCES_M, VECTOR9_MASSES_KG)
    for k, capacity_nm in [(0.1615, 1.583), (0.2627, 2.574)]:
        fit = dataclasses.replace(base, k=k)
        assert capacity_from_fit(fit, 0.01).capacity_nm == pytest.approx(capacity_nm, abs=5e-4)


def independent_fit(distances_m, masses_kg, level):
    """The same fit by another route: numpy lstsq on the design column 1/l, scipy's t."""
    x = 1.0 / np.asarray(distances_m, dtype=float)
    m = np.asarray(masses_kg, dtype=float)
    (k,), *_ = np.linalg.lstsq(x[:, None], m, rcond=None)
    residuals = m - k * x
    sse = float(residuals @ residuals)
    sst = float(((m - m.mean()) ** 2).sum())
    dfe = len(m) - 1
    rmse = math.sqrt(sse / dfe)
    se = rmse / math.sqrt(float(x @ x))
    t = float(stats.t.ppf((1 + level) / 2, dfe))
    return {
        "k": float(k),
        "sse": sse,
        "sst": sst,
        "r2": 1 - sse / sst,
        "rmse": rmse,
        "se": se,
        "t": t,
        "lo": float(k) - t * se,
        "hi": float(k) + t * se,
    }


@pytest.mark.parametrize("seed", range(20))
def test_agrees_with_independent_implementation(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 40))
    k_true = rng.uniform(0.05, 0.5)
    distances = rng.uniform(0.03, 0.6, n)
    masses = k_true / distances + rng.normal(0, rng.uniform(0.001, 0.3), n)
    level = float(rng.choice([0.9, 0.95, 0.99]))
    fit = fit_inverse_distance(distances, masses, level=level)
    ref = independent_fit(distances, masses, level)
    assert fit.k == pytest.approx(ref["k"], rel=1e-9)
    assert fit.sse == pytest.approx(ref["sse"], rel=1e-9)
    assert fit.sst == pytest.approx(ref["sst"], rel=1e-9)
    assert fit.r2 == pytest.approx(ref["r2"], rel=1e-9)
    assert fit.rmse == pytest.approx(ref["rmse"], rel=1e-9)
    assert fit.se == pytest.approx(ref["se"], rel=1e-9)
    assert fit.t == pytest.approx(ref["t"], rel=1e-12)
    assert fit.k_ci[0] == pytest.approx(ref["lo"], rel=1e-9)
    assert fit.k_ci[1] == pytest.approx(ref["hi"], rel=1e-9)


def test_near_perfect_fit_keeps_full_precision():
    # R² = 1 − 1e-20: the naive Σm² − k̂Σxm loses every digit of SSE here.
    distances = np.linspace(0.1, 0.5, 9)
    masses = [0.2 / d * (1 + 1e-10 * (-1) ** i) for i, d in enumerate(distances)]
    fit = fit_inverse_distance(distances, masses)
    ref = exact_reference(distances, masses)
    assert_matches_exact(fit, ref, rel=1e-15)
    naive_sse = sum(m * m for m in masses) - fit.k * sum(
        m / d for m, d in zip(masses, distances, strict=True)
    )
    assert abs(naive_sse - fit.sse) > 1e3 * fit.sse  # the hazard is real for this data


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=nasty_data(), level=st.sampled_from([0.5, 0.9, 0.99, 0.999]))
def test_batch_fit_is_exact_on_nasty_data(data, level):
    distances, masses = data
    fit = fit_inverse_distance(distances, masses, level=level)
    assert_matches_exact(fit, exact_reference(distances, masses))


def test_all_equal_masses_give_nan_r2_not_an_error():
    fit = fit_inverse_distance([0.1, 0.2, 0.3], [0.5, 0.5, 0.5])
    assert fit.sst == 0.0
    assert math.isnan(fit.r2)
    assert fit.sse > 0 and math.isfinite(fit.k_ci[0])
    summary = fit_summary(fit, capacity_from_fit(fit, 0.01)).as_json()
    assert math.isnan(summary["r2"])


def test_perfect_fit_has_zero_width_bounds():
    fit = fit_inverse_distance([0.5, 0.25], [1.0, 2.0])
    assert fit.k == 0.5 and fit.sse == 0.0 and fit.r2 == 1.0
    assert fit.rmse == 0.0 and fit.se == 0.0 and fit.k_ci == (0.5, 0.5)


def test_r2_can_be_negative_without_offset():
    # Masses rising with distance: the through-origin inverse model is worse than the mean.
    fit = fit_inverse_distance([0.1, 0.2, 0.3, 0.4], [0.1, 0.2, 0.3, 0.4])
    assert fit.r2 < 0
    ref = exact_reference([0.1, 0.2, 0.3, 0.4], [0.1, 0.2, 0.3, 0.4])
    assert fit.r2 == pytest.approx(float(ref["r2"]), rel=1e-15)


@pytest.mark.parametrize(
    ("distances", "masses", "level", "message"),
    [
        ([0.1], [1.0], 0.99, "at least 2"),
        ([], [], 0.99, "at least 2"),
        ([0.1, 0.0], [1.0, 2.0], 0.99, "point 2: distance_m = 0.0; allowed: finite and > 0 m"),
        ([0.1, -0.2], [1.0, 2.0], 0.99, "distance_m = -0.2"),
        ([0.1, math.nan], [1.0, 2.0], 0.99, "point 2: distance_m = nan"),
        ([0.1, 0.2], [1.0, math.inf], 0.99, "point 2: mass_kg = inf; allowed: finite"),
        ([0.1, 0.2], [1.0, 2.0], 0.0, "open interval (0, 1)"),
        ([0.1, 0.2], [1.0, 2.0], 1.0, "open interval (0, 1)"),
        ([0.1, 0.2], [1.0, 2.0], math.nan, "open interval (0, 1)"),
        ([0.1, 0.2], [1.0], 0.99, "2 distances but 1 masses"),
        ([[0.1, 0.2]], [[1.0, 2.0]], 0.99, "one-dimensional"),
    ],
    ids=["one", "none", "zero-distance", "negative", "nan", "inf-mass", "level0", "level1", "level-nan",
         "lengths", "2d"],
)  # fmt: skip
def test_invalid_input_raises_value_error(distances, masses, level, message):
    with pytest.raises(ValueError) as excinfo:
        fit_inverse_distance(distances, masses, level=level)
    assert message in str(excinfo.value)


def test_capacity_from_fit_validates_inputs():
    fit = fit_inverse_distance(VECTOR9_DISTANCES_M, VECTOR9_MASSES_KG)
    for radius in (0.0, -0.01, math.nan, math.inf):
        with pytest.raises(ValueError, match="radius_m"):
            capacity_from_fit(fit, radius)
    with pytest.raises(ValueError, match="g = "):
        capacity_from_fit(fit, 0.01, g=0.0)
    with pytest.raises(ValueError, match="unknown capacity constant"):
        capacity_from_fit(fit, 0.01, constant="papr")
    custom = capacity_from_fit(fit, 0.01, constant=7.0, g=9.81)
    assert custom.constant == "custom" and custom.c == 7.0
    assert custom.capacity_nm == pytest.approx(fit.k * 9.81, rel=1e-15)
    assert custom.capacity_se_nm == pytest.approx(fit.se * 9.81, rel=1e-15)
    assert custom.mu_delta0_pa == pytest.approx(fit.k * 9.81 / (7.0 * 0.01**3), rel=1e-14)


def test_summary_dict_has_exactly_the_design_keys_in_order():
    fit = fit_inverse_distance(VECTOR9_DISTANCES_M, VECTOR9_MASSES_KG)
    capacity = capacity_from_fit(fit, 0.012, constant="derived")
    summary = fit_summary(fit, capacity).as_json()
    assert tuple(summary) == SUMMARY_KEYS == (
        "n", "k", "k_ci", "sse", "sst", "r2", "rmse", "dfe", "se", "level", "constant", "c",
        "radius_m", "mu_delta0_pa", "mu_delta0_ci_pa", "capacity_nm", "capacity_ci_nm",
    )  # fmt: skip
    assert type(summary["n"]) is int and type(summary["dfe"]) is int
    assert all(type(summary[key]) is list and len(summary[key]) == 2 for key in
               ("k_ci", "mu_delta0_ci_pa", "capacity_ci_nm"))  # fmt: skip
    assert summary["constant"] == "derived" and summary["c"] == pytest.approx(math.pi**2)
    assert summary["k_ci"] == list(fit.k_ci)
    assert summary["capacity_ci_nm"] == pytest.approx([fit.k_ci[0] * 9.8, fit.k_ci[1] * 9.8])
    json.dumps(summary, allow_nan=False)
