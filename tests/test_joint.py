"""One joint: capacity constant, capacity, contact solution, stress quadrature (docs/model.md §2, §8)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model.joint import (
    DERIVED_CONSTANT,
    PAPER_CONSTANT,
    CapacityConstant,
    contact_stresses,
    contact_wrench,
    joint_capacity_nm,
    mu_delta0_pa_from_capacity,
    resolve_constant,
    solve_contact,
)

REL = 1e-6


def test_named_constants():
    assert resolve_constant() == CapacityConstant("paper", 5.4397)
    assert resolve_constant("paper").value == PAPER_CONSTANT == 5.4397
    assert resolve_constant("derived") == CapacityConstant("derived", math.pi**2)
    assert pytest.approx(9.8696044, rel=1e-8) == DERIVED_CONSTANT
    assert resolve_constant(7.5) == CapacityConstant("custom", 7.5)
    custom = CapacityConstant("mine", 3.0)
    assert resolve_constant(custom) is custom


@pytest.mark.parametrize("bad", ["papers", "", -1.0, 0, float("nan"), float("inf"), True, None, [1.0]])
def test_bad_constants_name_what_is_allowed(bad):
    with pytest.raises(ValueError, match=r"paper.*derived.*positive"):
        resolve_constant(bad)


def test_capacity_constant_rejects_bad_value():
    with pytest.raises(ValueError):
        CapacityConstant("x", -2.0)


def test_vector_1_joint_capacity():
    assert joint_capacity_nm(1e5, 0.01, "derived") == pytest.approx(0.98696044, rel=REL)
    assert joint_capacity_nm(1e5, 0.01, "paper") == pytest.approx(0.54397, rel=REL)
    assert joint_capacity_nm(1e5, 0.01) == pytest.approx(0.54397, rel=REL)  # paper is the default


@pytest.mark.parametrize(
    ("k", "derived_pa", "paper_pa"), [(0.1615, 160361.04, 290953.55), (0.2627, 260847.33, 473272.42)]
)
def test_vectors_10_11_mu_delta0_from_capacity(k, derived_pa, paper_pa):
    capacity = k * 9.8
    assert mu_delta0_pa_from_capacity(capacity, 0.01, "derived") == pytest.approx(derived_pa, rel=REL)
    assert mu_delta0_pa_from_capacity(capacity, 0.01, "paper") == pytest.approx(paper_pa, rel=REL)


def test_capacity_broadcasts_and_inverts():
    mu_delta0 = np.array([[1e5], [2e5]])
    radius = np.array([0.005, 0.01, 0.02])
    capacity = joint_capacity_nm(mu_delta0, radius, "derived")
    assert capacity.shape == (2, 3)
    np.testing.assert_allclose(capacity, math.pi**2 * mu_delta0 * radius**3, rtol=1e-15)
    back = mu_delta0_pa_from_capacity(capacity, radius, "derived")
    np.testing.assert_allclose(back, np.broadcast_to(mu_delta0, (2, 3)), rtol=1e-14)
    assert isinstance(joint_capacity_nm(1e5, 0.01), float)


@pytest.mark.parametrize(
    ("mu_delta0", "radius"), [(1e5, 0.0), (1e5, -0.01), (-1.0, 0.01), (float("nan"), 0.01)]
)
def test_capacity_rejects_bad_inputs(mu_delta0, radius):
    with pytest.raises(ValueError, match="allowed"):
        joint_capacity_nm(mu_delta0, radius)


def test_vector_2_single_joint_solution():
    s = solve_contact([3.0, 0.0, 0.0], [0.0, 0.0, 0.05], 0.01, 2e5, "derived")
    assert s.mu == pytest.approx(0.0759908877, rel=REL)
    assert s.theta_rad == pytest.approx(0.0892866291, rel=REL)
    assert s.delta_max_pa == pytest.approx(7133.4434, rel=REL)
    assert s.compressive is True
    assert s.constant.name == "derived"
    assert s.force_n == 3.0
    assert s.lever_arm_m == pytest.approx(0.05, rel=1e-15)
    assert s.moment_nm == pytest.approx(0.15, rel=1e-15)
    # The paper constant only rescales mu (c cancels out of f l = c mu delta0 R^3).
    p = solve_contact([3.0, 0.0, 0.0], [0.0, 0.0, 0.05], 0.01, 2e5)
    assert p.constant.name == "paper"
    assert p.mu == pytest.approx(s.mu * math.pi**2 / 5.4397, rel=1e-12)


def test_vector_3_quadrature_balances_the_load():
    s = solve_contact([3.0, 0.0, 0.0], [0.0, 0.0, 0.05], 0.01, 2e5, "derived")
    wrench = contact_wrench(s)
    np.testing.assert_allclose(wrench.force_n, [-3.0, 0.0, 0.0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(wrench.moment_nm, [0.0, -0.15, 0.0], rtol=0, atol=1e-8)


def test_quadrature_converges_spectrally():
    s = solve_contact([3.0, 0.0, 0.0], [0.0, 0.0, 0.05], 0.01, 2e5, "derived")
    errors = [np.abs(contact_wrench(s, n, n).force_n - [-3.0, 0.0, 0.0]).max() for n in (4, 6, 8, 12)]
    assert errors[0] > 1e-3  # too coarse: the test can see a wrong rule
    assert errors[1] < errors[0] / 100 and errors[2] < errors[1] / 100
    assert errors[3] < 1e-12


def test_paper_constant_moment_is_scaled_by_pi2_over_c():
    s = solve_contact([3.0, 0.0, 0.0], [0.0, 0.0, 0.05], 0.01, 2e5, "paper")
    wrench = contact_wrench(s)
    np.testing.assert_allclose(wrench.force_n, [-3.0, 0.0, 0.0], atol=1e-8)
    assert wrench.moment_nm[1] == pytest.approx(-0.15 * math.pi**2 / 5.4397, rel=1e-9)


def test_stresses_at_known_points():
    s = solve_contact([3.0, 0.0, 0.0], [0.0, 0.0, 0.05], 0.01, 2e5, "derived")
    e = np.array([math.cos(s.theta_rad), 0.0, math.sin(s.theta_rad)])
    sigma, t = contact_stresses(s, np.stack([e, -e, [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(
        sigma, [2e5 + s.delta_max_pa, 2e5 - s.delta_max_pa, 2e5 + s.delta_max_pa * e[2]]
    )
    # t = (n x y)/|n x y| straight from the definition.
    np.testing.assert_allclose(t[2], np.cross([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]))


unit = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=40, deadline=None)
@given(
    force=st.tuples(unit, unit, unit).filter(lambda v: np.linalg.norm(v) > 0.05),
    point=st.tuples(unit, unit, unit),
    scale=st.floats(0.5, 20.0),
)
def test_any_force_at_any_point_is_balanced(force, point, scale):
    force_n = scale * np.array(force)
    point_m = 0.05 * np.array(point)
    s = solve_contact(force_n, point_m, 0.01, 2e5, "derived")
    assert s.force_n == pytest.approx(np.linalg.norm(force_n))
    assert s.moment_nm == pytest.approx(np.linalg.norm(np.cross(point_m, force_n)), abs=1e-15)
    np.testing.assert_allclose(s.contact_frame.T @ s.contact_frame, np.eye(3), atol=1e-12)
    wrench = contact_wrench(s, 24, 24)
    np.testing.assert_allclose(wrench.force_n, -force_n, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(wrench.moment_nm, -np.cross(point_m, force_n), rtol=0, atol=1e-10 * scale)


def test_load_on_line_of_action_needs_no_friction():
    s = solve_contact([0.0, 0.0, 2.0], [0.0, 0.0, 0.05], 0.01, 2e5, "derived")
    assert s.mu == 0.0 and s.theta_rad == 0.0 and s.moment_nm == 0.0
    wrench = contact_wrench(s)
    np.testing.assert_allclose(wrench.force_n, [0.0, 0.0, -2.0], atol=1e-9)
    np.testing.assert_allclose(wrench.moment_nm, 0.0, atol=1e-12)


def test_tensile_contact_is_flagged():
    # A large force on a small preload: delta_max exceeds delta0.
    s = solve_contact([1000.0, 0.0, 0.0], [0.0, 0.0, 0.001], 0.01, 1e3, "derived")
    assert s.delta_max_pa > s.delta0_pa and s.compressive is False


@pytest.mark.parametrize(
    "kwargs",
    [
        {"force_n": [1.0, 0.0], "point_m": [0, 0, 1], "radius_m": 0.01, "delta0_pa": 1e5},
        {"force_n": [1.0, 0.0, 0.0], "point_m": [0, 0, float("nan")], "radius_m": 0.01, "delta0_pa": 1e5},
        {"force_n": [1.0, 0.0, 0.0], "point_m": [0, 0, 1], "radius_m": 0.0, "delta0_pa": 1e5},
        {"force_n": [1.0, 0.0, 0.0], "point_m": [0, 0, 1], "radius_m": 0.01, "delta0_pa": -1.0},
    ],
)
def test_solve_contact_rejects_bad_inputs(kwargs):
    with pytest.raises(ValueError, match="allowed"):
        solve_contact(**kwargs)
