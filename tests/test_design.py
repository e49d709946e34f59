"""The adaptive planner (model/design.py): which distance next, the lack-of-fit test, when to stop."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from model.design import (
    Choice,
    DesignSettings,
    Observation,
    StopReason,
    current_estimate,
    information_per_trial,
    lack_of_fit,
    plan_next,
    predicted_slip_mass_kg,
    scale_upper_factor,
)
from model.k_estimators import KEstimate

K = 0.1615  # kg·m
G = 9.8
SETTINGS = DesignSettings(
    0.03, 0.25, distance_count=8, target_half_width_rel=0.02, max_trials=24, min_trials=6
)
NO_LIMIT = math.inf


def estimate(*, a_kg: float, b: float, k: float = K, half_rel: float = 0.1, n: int = 5) -> KEstimate:
    """An estimate as an estimator would give it, with the scatter model the test needs."""
    model = "mixed" if a_kg and b else ("additive" if a_kg else "multiplicative")
    half = half_rel * k
    return KEstimate("auto", model, n, 0, k, (k - half, k + half), half / 3, 0.99, a_kg, b)


def exact(distances: list[float]) -> list[Observation]:
    return [Observation(d, K / d) for d in distances]


def run_series(settings: DesignSettings, a_kg: float, b: float, trials: int) -> list[float]:
    """The distances the planner picks for `trials` trials of exact data, given the scatter model."""
    observations: list[Observation] = []
    for _ in range(trials):
        est = estimate(a_kg=a_kg, b=b) if len(observations) >= 2 else None
        step = plan_next(settings, observations, est, max_slip_force_n=NO_LIMIT, g=G)
        assert step.stop is None and step.next_distance_m is not None
        observations.append(Observation(step.next_distance_m, K / step.next_distance_m))
    return [o.distance_m for o in observations]


def test_startup_spreads_from_the_longest_distance_to_the_shortest():
    assert SETTINGS.candidates_m[0] == 0.03 and SETTINGS.candidates_m[-1] == 0.25
    distances = run_series(SETTINGS, a_kg=0.126, b=0.0, trials=3)
    assert distances == list(SETTINGS.startup_m)
    assert distances[0] == 0.25 and distances[-1] == 0.03 and distances[0] > distances[1] > distances[2]


def test_additive_scatter_chooses_the_short_distances():
    distances = run_series(SETTINGS, a_kg=0.126, b=0.0, trials=16)
    after_startup = distances[SETTINGS.startup_trials :]
    # Information 1/(a l)^2: the shortest distance carries 4x the next one; only the spread rule
    # sends a trial to the upper half of the range.
    assert after_startup.count(0.03) >= 11
    spread = [d for d in distances if d >= SETTINGS.spread_from_m]
    assert len(spread) >= SETTINGS.min_spread_fraction * len(distances)


def test_multiplicative_scatter_spreads_over_the_range():
    distances = run_series(SETTINGS, a_kg=0.0, b=0.085, trials=19)
    counts = {d: distances.count(d) for d in SETTINGS.candidates_m}
    # Every distance carries the same information: the least used goes next, so all 8 are used, evenly.
    assert min(counts.values()) >= 2 and max(counts.values()) <= 3


def test_mixed_scatter_uses_the_short_distances_within_reach_of_the_best():
    # a = 0.05 kg, b = 0.085: 0.03, 0.061 and 0.093 m are within 10 % of the best information, 0.124 m is not.
    info = [information_per_trial(d, K, 0.05, 0.085) for d in SETTINGS.candidates_m]
    assert info == sorted(info, reverse=True)
    near = set(SETTINGS.candidates_m[:3])
    distances = run_series(SETTINGS, a_kg=0.05, b=0.085, trials=15)[SETTINGS.startup_trials :]
    far = {d for d in SETTINGS.candidates_m if d >= SETTINGS.spread_from_m}
    assert set(distances) <= near | far
    assert all(distances.count(d) >= 3 for d in near)


def test_the_force_limit_is_respected():
    # 30 N is k·g/l at l = 0.053 m: with the estimate's margins, only distances well beyond are safe.
    limit_n = 30.0
    observations = exact([0.25, 0.155714286])
    est = estimate(a_kg=0.0, b=0.085)
    for _ in range(10):
        step = plan_next(SETTINGS, observations, est, max_slip_force_n=limit_n, g=G)
        assert step.next_distance_m is not None
        assert predicted_slip_mass_kg(step.next_distance_m, est, observations) * G <= limit_n
        assert all(
            predicted_slip_mass_kg(d, est, observations) * G <= limit_n for d in step.safe_candidates_m
        )
        assert step.next_distance_m >= 0.09
        observations.append(Observation(step.next_distance_m, K / step.next_distance_m))
    # The start-up's 0.03 m was replaced by the shortest safe distance.
    first = plan_next(SETTINGS, exact([0.25, 0.155714286]), est, max_slip_force_n=limit_n, g=G)
    assert first.choice is Choice.STARTUP and first.next_distance_m == first.safe_candidates_m[0] > 0.03


def test_before_any_trial_only_the_longest_distance_is_tried():
    step = plan_next(SETTINGS, [], None, max_slip_force_n=NO_LIMIT, g=G)
    assert step.safe_candidates_m == (0.25,) and step.next_distance_m == 0.25


def test_no_slip_rules_out_that_distance_and_shorter_ones():
    observations = [Observation(0.25, K / 0.25), Observation(0.155714286, 5.0, censored=True)]
    step = plan_next(SETTINGS, observations, None, max_slip_force_n=NO_LIMIT, g=G)
    assert min(step.safe_candidates_m) > 0.155714286


def test_no_slip_at_the_longest_distance_stops_the_series():
    step = plan_next(SETTINGS, [Observation(0.25, 5.0, censored=True)], None, max_slip_force_n=50.0, g=G)
    assert step.stop is StopReason.NO_SAFE_DISTANCE and step.next_distance_m is None


def test_stops_on_target_but_not_before_min_trials():
    # 0.5 %: within the 2 % target (the default stop takes the bound as estimated).
    tight = estimate(a_kg=0.0, b=0.01, half_rel=0.005)
    five = exact([0.25, 0.155714286, 0.03, 0.03, 0.03])
    step = plan_next(SETTINGS, five, tight, max_slip_force_n=NO_LIMIT, g=G)
    assert step.stop is None  # 5 < min_trials = 6
    six = [*five, Observation(0.03, K / 0.03)]
    step = plan_next(SETTINGS, six, tight, max_slip_force_n=NO_LIMIT, g=G)
    assert step.stop is StopReason.TARGET_REACHED and step.next_distance_m is None
    assert step.half_width_rel == pytest.approx(0.005)
    wide = estimate(a_kg=0.0, b=0.03, half_rel=0.025)  # beyond the target
    assert plan_next(SETTINGS, six, wide, max_slip_force_n=NO_LIMIT, g=G).stop is None


def test_the_stop_allows_for_a_scatter_that_looks_small_by_chance():
    settings = DesignSettings(
        0.03, 0.25, target_half_width_rel=0.05, max_trials=24, min_trials=10, stop_scale_confidence=0.75
    )
    ten = exact([0.25, 0.14, 0.03, 0.03, 0.061, 0.03, 0.25, 0.03, 0.061, 0.03])
    at_target = estimate(a_kg=0.0, b=0.05, half_rel=0.05, n=10)
    # Taken at face value (confidence 0) the bound meets the target and the series stops ...
    face_value = replace(settings, stop_scale_confidence=0.0)
    assert (
        plan_next(face_value, ten, at_target, max_slip_force_n=NO_LIMIT, g=G).stop
        is StopReason.TARGET_REACHED
    )
    # ... but the scale of 10 slips may be sqrt(9 / 5.899) = 1.235 times its estimate at 75 %
    # (chi-square on 9 df, lower quartile 5.899 from tables), so at that confidence it goes on.
    step = plan_next(settings, ten, at_target, max_slip_force_n=NO_LIMIT, g=G)
    assert step.stop is None and step.next_distance_m is not None
    assert step.half_width_rel == pytest.approx(0.05)
    assert step.stop_half_width_rel == pytest.approx(0.05 * 1.2352, rel=1e-3)
    assert "6.18 % at the scatter's upper limit" in step.text(settings)
    narrower = estimate(a_kg=0.0, b=0.05, half_rel=0.05 / 1.236, n=10)
    assert (
        plan_next(settings, ten, narrower, max_slip_force_n=NO_LIMIT, g=G).stop is StopReason.TARGET_REACHED
    )


def test_scale_upper_factor():
    assert scale_upper_factor(9, 0.0) == 1.0
    assert scale_upper_factor(9, 0.75) == pytest.approx(math.sqrt(9 / 5.899), rel=1e-3)
    assert scale_upper_factor(0, 0.75) == math.inf
    # More confidence or fewer degrees of freedom: a larger factor; many degrees of freedom: near 1.
    assert scale_upper_factor(9, 0.9) > scale_upper_factor(9, 0.75) > scale_upper_factor(23, 0.75) > 1.0
    assert scale_upper_factor(10_000, 0.75) == pytest.approx(1.0, abs=0.01)


def test_stops_on_budget():
    settings = DesignSettings(0.03, 0.25, max_trials=7, min_trials=6)
    wide = estimate(a_kg=0.0, b=0.2, half_rel=0.2)
    observations = exact([0.25, 0.14, 0.03, 0.03, 0.03, 0.03])
    assert plan_next(settings, observations, wide, max_slip_force_n=NO_LIMIT, g=G).stop is None
    observations.append(Observation(0.03, K / 0.03))
    step = plan_next(settings, observations, wide, max_slip_force_n=NO_LIMIT, g=G)
    assert step.stop is StopReason.BUDGET
    assert "budget of 7" in step.text(settings)


def test_the_planner_is_deterministic():
    rng = np.random.default_rng(5)
    data = [Observation(d, K / d * (1 + 0.08 * rng.standard_normal())) for d in SETTINGS.candidates_m * 2]
    est = current_estimate(SETTINGS, data)
    first = plan_next(SETTINGS, data, est, max_slip_force_n=60.0, g=G)
    again = plan_next(
        SETTINGS, list(data), current_estimate(SETTINGS, list(data)), max_slip_force_n=60.0, g=G
    )
    assert first == again


def test_current_estimate_needs_two_slips():
    assert current_estimate(SETTINGS, exact([0.25])) is None
    assert current_estimate(SETTINGS, [Observation(0.25, 0.6), Observation(0.2, 0.9, censored=True)]) is None
    est = current_estimate(SETTINGS, [Observation(0.25, 0.64), Observation(0.2, 0.82)])
    assert est is not None and est.estimator == "auto" and est.n == 2


# ------------------------------------------------------------------------------------------ lack of fit


def test_lack_of_fit_pure_error_f_rejects_an_offset_and_accepts_the_law():
    rng = np.random.default_rng(1)
    distances = np.repeat(SETTINGS.candidates_m, 3)
    noise = 0.02 * rng.standard_normal(len(distances))
    good = lack_of_fit(distances, K / distances + noise, 0.02, 0.0, K)
    assert good.test == "pure_error_f" and good.df == (7, 16) and not good.rejected
    assert good.p_value > 0.01
    offset = lack_of_fit(distances, K / distances + 0.3 + noise, 0.02, 0.0, K)
    assert offset.test == "pure_error_f" and offset.rejected and offset.p_value < 1e-6
    assert "REJECTED" in offset.text()


def test_lack_of_fit_without_replicates_tests_an_offset():
    distances = np.array(SETTINGS.candidates_m)
    noise = np.array([0.01, -0.02, 0.015, -0.01, 0.0, 0.02, -0.015, 0.005])
    good = lack_of_fit(distances, K / distances + noise, 0.02, 0.0, K)
    assert good.test == "offset_t" and good.df == (0, 6) and not good.rejected
    bad = lack_of_fit(distances, K / distances + 0.4 + noise, 0.02, 0.0, K)
    assert bad.rejected


def test_lack_of_fit_needs_two_distances_and_three_slips():
    assert lack_of_fit([0.1, 0.1, 0.1], [1.6, 1.7, 1.5], 0.1, 0.0, K).test == "none"
    assert lack_of_fit([0.1, 0.2], [1.6, 0.8], 0.1, 0.0, K).test == "none"
    assert "not testable" in lack_of_fit([0.1], [1.6], 0.1, 0.0, K).text()


def test_settings_are_checked():
    with pytest.raises(ValueError, match="distance range"):
        DesignSettings(0.25, 0.03)
    with pytest.raises(ValueError, match="startup_trials"):
        DesignSettings(0.03, 0.25, max_trials=4, min_trials=6)
    with pytest.raises(ValueError, match="stop_scale_confidence"):
        DesignSettings(0.03, 0.25, stop_scale_confidence=1.0)
    with pytest.raises(ValueError, match="estimator"):
        DesignSettings(0.03, 0.25, estimator="best")  # type: ignore[arg-type]
