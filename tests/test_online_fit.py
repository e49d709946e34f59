"""The online fit: a pure O(1) step function whose estimate equals the batch fit after every update."""

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from model.fit import InverseFit, fit_inverse_distance
from model.online_fit import OnlineFitState, online_fit_estimate, online_fit_init, online_fit_update
from tests.fit_reference import (
    VECTOR9_DISTANCES_M,
    VECTOR9_MASSES_KG,
    assert_matches_exact,
    exact_reference,
    nasty_data,
)

FIELDS = ("k", "sse", "sst", "r2", "rmse", "se", "t")


def assert_same_fit(online: InverseFit, batch: InverseFit, rel: float = 1e-12) -> None:
    assert online.n == batch.n and online.dfe == batch.dfe and online.level == batch.level
    for name in FIELDS:
        a, b = getattr(online, name), getattr(batch, name)
        if math.isnan(b):
            assert math.isnan(a), name
        else:
            assert a == pytest.approx(b, rel=rel, abs=0), name
    scale = abs(batch.k) + batch.t * batch.se
    for a, b in zip(online.k_ci, batch.k_ci, strict=True):
        assert a == pytest.approx(b, abs=rel * scale)


def test_vector_9_online_matches_model():
    state = online_fit_init()
    for d, m in zip(VECTOR9_DISTANCES_M, VECTOR9_MASSES_KG, strict=True):
        state = online_fit_update(state, d, m)
    fit = online_fit_estimate(state, level=0.99)
    assert fit is not None
    assert fit.k == pytest.approx(0.16698706, rel=1e-6)
    assert fit.sse == pytest.approx(0.00399723, rel=1e-6)
    assert fit.k_ci == pytest.approx((0.14865418, 0.18531994), rel=1e-6)


def test_estimate_is_none_before_two_points():
    state = online_fit_init()
    assert state.n == 0 and online_fit_estimate(state) is None
    state = online_fit_update(state, 0.1, 1.0)
    assert state.n == 1 and online_fit_estimate(state) is None
    state = online_fit_update(state, 0.2, 0.5)
    assert online_fit_estimate(state) is not None


def test_update_is_pure():
    start = online_fit_update(online_fit_init(), 0.1, 1.7)
    snapshot = OnlineFitState(start.sums)
    after = online_fit_update(start, 0.2, 0.78)
    assert start == snapshot and after != start
    # Same inputs, same state: the step function has no hidden state.
    assert online_fit_update(start, 0.2, 0.78) == after


@pytest.mark.parametrize(
    ("distance", "mass", "message"),
    [(0.0, 1.0, "distance_m = 0.0"), (-1.0, 1.0, "distance_m"), (math.nan, 1.0, "distance_m"),
     (0.1, math.nan, "mass_kg = nan"), (0.1, math.inf, "mass_kg"), ("x", 1.0, "allowed: numbers")],
)  # fmt: skip
def test_update_rejects_bad_pairs(distance, mass, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        online_fit_update(online_fit_init(), distance, mass)


def test_estimate_rejects_bad_level():
    state = online_fit_update(online_fit_update(online_fit_init(), 0.1, 1.0), 0.2, 0.6)
    for level in (0.0, 1.0, -0.5, 2.0):
        with pytest.raises(ValueError, match="open interval"):
            online_fit_estimate(state, level=level)


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=nasty_data(), level=st.sampled_from([0.9, 0.99]))
def test_online_equals_batch_after_every_update(data, level):
    distances, masses = data
    state = online_fit_init()
    for i, (d, m) in enumerate(zip(distances, masses, strict=True), start=1):
        state = online_fit_update(state, d, m)
        online = online_fit_estimate(state, level=level)
        if i < 2:
            assert online is None
            continue
        batch = fit_inverse_distance(distances[:i], masses[:i], level=level)
        assert_same_fit(online, batch)
        assert_matches_exact(online, exact_reference(distances[:i], masses[:i]))


@settings(max_examples=30, deadline=None)
@given(
    pairs=st.lists(
        st.tuples(st.floats(1e-3, 1e3), st.floats(-1e3, 1e3)),
        min_size=2,
        max_size=300,
    )
)
def test_online_equals_batch_on_long_random_sequences(pairs):
    state = online_fit_init()
    for d, m in pairs:
        state = online_fit_update(state, d, m)
    distances, masses = zip(*pairs, strict=True)
    assert_same_fit(online_fit_estimate(state), fit_inverse_distance(distances, masses))


def test_no_cancellation_when_r2_is_one_to_twenty_digits():
    distances = [0.05 + 0.01 * i for i in range(50)]
    masses = [0.1615 / d * (1 + 1e-10 * math.sin(7 * i)) for i, d in enumerate(distances)]
    state = online_fit_init()
    for d, m in zip(distances, masses, strict=True):
        state = online_fit_update(state, d, m)
    fit = online_fit_estimate(state)
    assert 1 - fit.r2 < 1e-18
    assert_matches_exact(fit, exact_reference(distances, masses), rel=1e-15)
