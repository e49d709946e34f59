"""Per-joint capacity estimation from link-validation slips: calibration on synthetic truth, behaviour."""

import math

import numpy as np
import pytest

from model.capacity_grid_filter import (
    LinkCapacityPrior,
    link_estimator_estimates,
    link_estimator_init,
    link_estimator_update,
)
from model.fit import capacity_from_fit, fit_inverse_distance


def simulate_link_trials(seed, *, identify, n_trials=8, level=0.9, sigma=0.05, prior_sd=0.3):
    """Truth drawn from the prior; each trial: per-joint scatter, the weakest-relative joint slips."""
    rng = np.random.default_rng(seed)
    prior_capacity = np.array([1.6, 1.2, 0.9])
    truth = prior_capacity * np.exp(prior_sd * rng.standard_normal(3))
    state = link_estimator_init(prior_capacity, np.full(3, prior_sd), obs_sd_log=sigma)
    for _ in range(n_trials):
        arms = rng.uniform(0.02, 0.2, 3)
        resisting = truth * np.exp(sigma * rng.standard_normal(3))
        ratio = resisting / arms
        joint = int(np.argmin(ratio))
        state = link_estimator_update(state, arms, float(ratio[joint]), joint + 1 if identify else None)
    est = link_estimator_estimates(state, level)
    return truth, est


@pytest.mark.slow
@pytest.mark.parametrize(
    ("identify", "tolerance"), [(True, 0.035), (False, 0.06)], ids=["identified", "unknown"]
)
def test_bounds_cover_the_truth_at_the_nominal_rate(identify, tolerance):
    covered = []
    widths = []
    for seed in range(300):
        truth, est = simulate_link_trials(seed, identify=identify)
        covered.extend((est.ci_lo_nm <= truth) & (truth <= est.ci_hi_nm))
        widths.extend(np.log(est.ci_hi_nm / est.ci_lo_nm))
    rate = float(np.mean(covered))
    assert abs(rate - 0.9) < tolerance, rate
    # And the data taught something: the prior's 90 % width in log is 2 * 1.645 * 0.3 = 0.99.
    assert np.median(widths) < 0.3


def test_identified_slip_matches_the_conjugate_gaussian_update():
    prior_sd, sigma = 0.2, 0.05
    state = link_estimator_init([1.0, 1.0], [prior_sd, prior_sd], obs_sd_log=sigma)
    arms = np.array([0.1, 0.05])
    state = link_estimator_update(state, arms, 9.0, slipped_joint=1)
    est = link_estimator_estimates(state, level=0.95)
    observed = math.log(9.0 * 0.1)
    precision = 1 / prior_sd**2 + 1 / sigma**2
    mean = (observed / sigma**2) / precision
    sd = precision**-0.5
    assert math.log(est.capacity_nm[0]) == pytest.approx(mean, abs=2e-4)
    assert est.sd_log[0] == pytest.approx(sd, rel=2e-3)
    assert math.log(est.ci_hi_nm[0]) == pytest.approx(mean + 1.959964 * sd, abs=5e-4)
    assert state.last_slip_probabilities.tolist() == [1.0, 0.0]


def test_identified_slips_tighten_the_slipped_joint_and_only_raise_held_joints():
    state = link_estimator_init([1.0, 0.9, 0.8], [0.2, 0.2, 0.2])
    before = link_estimator_estimates(state, 0.9)
    # Joint 2 slips at 8 N with 0.1 m: moment 0.8 N·m; joint 3 held 8 N × 0.09 m = 0.72 N·m.
    after_state = link_estimator_update(state, [0.05, 0.1, 0.09], 8.0, slipped_joint=2)
    after = link_estimator_estimates(after_state, 0.9)
    assert after.sd_log[1] < 0.5 * before.sd_log[1]
    assert after.capacity_nm[1] == pytest.approx(0.8, rel=0.03)
    for j in (0, 2):
        assert after.ci_lo_nm[j] >= before.ci_lo_nm[j]
        assert after.capacity_nm[j] >= before.capacity_nm[j]
        assert after.ci_hi_nm[j] >= before.ci_hi_nm[j] - 1e-12
    # Joint 3 held close to its prior median: its lower tail rises clearly.
    assert after.ci_lo_nm[2] > before.ci_lo_nm[2] * 1.05
    # Joint 1 held far below its capacity (8 × 0.05 = 0.4 N·m): practically no information.
    assert after.capacity_nm[0] == pytest.approx(before.capacity_nm[0], rel=1e-3)


def test_unloaded_joint_learns_nothing():
    state = link_estimator_init([1.0, 1.0], [0.2, 0.2])
    after = link_estimator_update(state, [0.1, 0.0], 9.0, None)
    np.testing.assert_allclose(after.log_weights[1], state.log_weights[1], atol=1e-12)
    assert after.last_slip_probabilities.tolist() == [1.0, 0.0]
    with pytest.raises(ValueError, match="lever arm 0 and cannot slip"):
        link_estimator_update(state, [0.1, 0.0], 9.0, 2)


def test_unknown_slip_with_an_obvious_culprit_equals_the_identified_update():
    state = link_estimator_init([1.0, 5.0, 5.0], [0.1, 0.1, 0.1])
    arms = [0.1, 0.05, 0.05]  # joint 1: C/d = 10 N, the others 100 N
    unknown = link_estimator_update(state, arms, 9.5, None)
    known = link_estimator_update(state, arms, 9.5, 1)
    assert unknown.last_slip_probabilities[0] > 1 - 1e-9
    a, b = link_estimator_estimates(unknown), link_estimator_estimates(known)
    np.testing.assert_allclose(a.capacity_nm, b.capacity_nm, rtol=1e-6)
    np.testing.assert_allclose(a.ci_lo_nm, b.ci_lo_nm, rtol=1e-6)


def test_unknown_slip_between_twins_splits_evenly():
    state = link_estimator_init([1.0, 1.0], [0.2, 0.2])
    after = link_estimator_update(state, [0.1, 0.1], 10.0, None)
    np.testing.assert_allclose(after.last_slip_probabilities, [0.5, 0.5], atol=1e-12)
    est = link_estimator_estimates(after)
    assert est.capacity_nm[0] == pytest.approx(est.capacity_nm[1], rel=1e-12)
    # A mixture of "slipped at 1 N·m" and "held at 1 N·m": the lower tail rises, the upper does not
    # move down by more than the mixture allows.
    before = link_estimator_estimates(state)
    assert est.ci_lo_nm[0] > before.ci_lo_nm[0]


def test_unknown_slip_favours_the_joint_weakest_relative_to_its_arm():
    state = link_estimator_init([1.0, 1.0, 1.0], [0.15, 0.15, 0.15])
    after = link_estimator_update(state, [0.05, 0.1, 0.08], 10.0, None)
    p = after.last_slip_probabilities
    assert p.argmax() == 1 and p.sum() == pytest.approx(1.0)
    assert p[1] > p[2] > p[0]


def test_prior_from_the_joint_estimation_fit():
    fit = fit_inverse_distance([0.1, 0.2, 0.4, 0.5], [1.7, 0.78, 0.41, 0.33])
    capacity = capacity_from_fit(fit, 0.01)
    prior = LinkCapacityPrior.from_capacity_estimate(capacity, n_joints=4)
    z = 2.5758293035489
    expected_sd = (capacity.capacity_ci_nm[1] - capacity.capacity_ci_nm[0]) / (2 * z * capacity.capacity_nm)
    np.testing.assert_allclose(prior.sd_log, expected_sd, rtol=1e-9)
    np.testing.assert_allclose(prior.capacity_nm, capacity.capacity_nm)
    widened = LinkCapacityPrior.from_capacity_estimate(capacity, 4, between_joint_sd_log=0.1)
    np.testing.assert_allclose(widened.sd_log, math.hypot(expected_sd, 0.1))
    state = link_estimator_init(capacity, n_joints=4, between_joint_sd_log=0.1)
    est = link_estimator_estimates(state, 0.99)
    np.testing.assert_allclose(est.capacity_nm, capacity.capacity_nm, rtol=1e-4)
    np.testing.assert_allclose(est.sd_log, widened.sd_log, rtol=1e-3)
    assert state.n_joints == 4 and state.last_slip_probabilities is None


def test_runner_style_positional_init_and_estimates():
    state = link_estimator_init(np.full(3, 1.5), np.full(3, 0.1))
    state = link_estimator_update(state, np.array([0.12, 0.1, 0.05]), 11.0, None)
    est = link_estimator_estimates(state, 0.99)
    assert est.capacity_nm.shape == est.ci_lo_nm.shape == est.ci_hi_nm.shape == (3,)
    assert np.all(est.ci_lo_nm < est.capacity_nm) and np.all(est.capacity_nm < est.ci_hi_nm)
    assert state.n_updates == 1
    with pytest.raises(ValueError):
        est.capacity_nm[0] = 1.0  # frozen arrays


@pytest.mark.parametrize(
    ("arms", "force", "joint", "message"),
    [
        ([0.1, 0.1], 5.0, 1, "shape (2,); allowed: (3,)"),
        ([0.1, -0.1, 0.1], 5.0, 1, "lever_arms_m[1] = -0.1"),
        ([0.1, math.nan, 0.1], 5.0, 1, "lever_arms_m[1] = nan"),
        ([0.0, 0.0, 0.0], 5.0, None, "every lever arm is 0"),
        ([0.1, 0.1, 0.1], 0.0, 1, "peak_force_n = 0.0"),
        ([0.1, 0.1, 0.1], math.inf, 1, "peak_force_n = inf"),
        ([0.1, 0.1, 0.1], 5.0, 0, "slipped_joint = 0; allowed: 1..3 or None"),
        ([0.1, 0.1, 0.1], 5.0, 4, "slipped_joint = 4"),
        ([0.1, 0.1, 0.1], 5.0, 1.0, "an integer 1..3"),
    ],
)
def test_update_rejects_bad_input(arms, force, joint, message):
    state = link_estimator_init([1.0, 1.0, 1.0], 0.1)
    with pytest.raises(ValueError) as excinfo:
        link_estimator_update(state, arms, force, joint)
    assert message in str(excinfo.value)


def test_init_rejects_bad_priors():
    with pytest.raises(ValueError, match="prior_sd_log is required"):
        link_estimator_init([1.0, 2.0])
    with pytest.raises(ValueError, match=r"prior capacity_nm\[1\] = -2.0"):
        link_estimator_init([1.0, -2.0], 0.1)
    with pytest.raises(ValueError, match="2 values for 3 joints"):
        link_estimator_init([1.0, 1.0, 1.0], [0.1, 0.1])
    with pytest.raises(ValueError, match="obs_sd_log"):
        link_estimator_init([1.0], 0.1, obs_sd_log=0.0)
    fit = fit_inverse_distance([0.5, 0.25], [1.0, 2.0])  # perfect fit: zero-width bounds
    with pytest.raises(ValueError, match="between_joint_sd_log > 0"):
        link_estimator_init(capacity_from_fit(fit, 0.01), n_joints=2)
    with pytest.raises(ValueError, match="needs n_joints"):
        link_estimator_init(capacity_from_fit(fit, 0.01))
    with pytest.raises(ValueError, match="open interval"):
        link_estimator_estimates(link_estimator_init([1.0], 0.1), level=1.0)
