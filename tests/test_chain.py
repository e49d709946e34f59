"""Chain statics: kinematics, joint moments, tolerance and slip load (docs/model.md §3; §8 values 4-8)."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from model.chain import (
    check_rigid_motion,
    forward_kinematics,
    joint_moment_norms,
    joint_moments_frame_free,
    joint_moments_recursive,
    lever_arms_m,
    planar_transforms,
    pose_from_xyz_rpy,
    predict_slip,
    tolerated,
)

REL = 1e-6
VECTOR_4_ANGLES = np.radians([0.0, 30.0, -20.0])
Q_TIP = np.array([0.0, 0.0, 0.03])
DOWN = np.array([0.0, -1.0, 0.0])


def vector_4_transforms():
    return planar_transforms(VECTOR_4_ANGLES, 0.03)


# ---------------------------------------------------------------- docs/model.md §8 reference values


def test_vector_4_forward_kinematics():
    poses = forward_kinematics(vector_4_transforms())
    assert poses.shape == (4, 4, 4)
    np.testing.assert_array_equal(poses[0], np.eye(4))
    np.testing.assert_allclose(poses[1, :3, 3], [0, 0, 0.03], rtol=REL, atol=1e-15)
    np.testing.assert_allclose(poses[2, :3, 3], [0, 0, 0.06], rtol=REL, atol=1e-15)
    np.testing.assert_allclose(poses[3, :3, 3], [0.015, 0, 0.0859808], rtol=REL, atol=1e-15)
    q_world = poses[3] @ np.append(Q_TIP, 1.0)
    # docs/model.md §8 prints these to 1e-7 m, which is 2e-6 relative for x: compare to half the last digit.
    np.testing.assert_allclose(q_world[:3], [0.0202094, 0, 0.1155250], rtol=0, atol=5e-8)
    np.testing.assert_allclose(
        q_world[:3],
        [
            0.015 + 0.03 * math.sin(math.radians(10)),
            0,
            0.06 + 0.03 * (math.cos(math.radians(30)) + math.cos(math.radians(10))),
        ],
        rtol=1e-14,
    )


def test_vector_5_joint_moments():
    expected = [1.1493376, 0.8612269, 0.5790670, 0.2940000]
    force = 9.8 * DOWN
    np.testing.assert_allclose(joint_moment_norms(vector_4_transforms(), Q_TIP, force), expected, rtol=REL)
    recursive = joint_moments_recursive(vector_4_transforms(), Q_TIP, force)
    np.testing.assert_allclose(np.linalg.norm(recursive, axis=-1), expected, rtol=REL)


def test_vector_6_payload_and_first_joint():
    p = predict_slip(vector_4_transforms(), [1.2, 0.9, 0.8], Q_TIP, DOWN)
    assert float(p.slip_mass_kg) == pytest.approx(1.3933610, rel=REL)
    assert int(p.first_slip_joint) == 1
    assert p.g == 9.8


def test_vector_7_slip_force_tip_and_base_moment():
    p = predict_slip(vector_4_transforms(), [2.0, 0.9, 0.8], Q_TIP, DOWN)
    assert float(p.slip_force_n) == pytest.approx(15.231399, rel=REL)
    assert float(p.slip_mass_kg) == pytest.approx(1.5542244, rel=REL)
    assert int(p.first_slip_joint) == 2
    assert float(p.tip_moment_nm) == pytest.approx(0.4569420, rel=REL)
    assert float(p.base_moment_nm) == pytest.approx(1.7863286, rel=REL)
    # The slipping joint is exactly at its capacity; index = joint number.
    assert p.joint_moments_at_slip_nm[2] == pytest.approx(0.9, rel=1e-12)
    np.testing.assert_array_equal(p.tied_joints, [False, True, False])


def test_vector_8_single_joint():
    t = np.eye(4)[None]
    expected = [[0.0, 0.2, 0.0], [0.0, 0.2, 0.0]]
    np.testing.assert_allclose(joint_moments_recursive(t, [0, 0, 0.1], [2, 0, 0]), expected, atol=1e-15)
    np.testing.assert_allclose(joint_moments_frame_free(t, [0, 0, 0.1], [2, 0, 0]), expected, atol=1e-15)


# ---------------------------------------------------------------- poses and rigid motions


def test_pose_from_xyz_rpy_order_is_z_y_x():
    # R = Rz(90°) Rx(90°) sends y to z; the other order (Rx Rz) would send it to -x.
    pose = pose_from_xyz_rpy([1.0, 2.0, 3.0], [math.pi / 2, 0.0, math.pi / 2])
    np.testing.assert_allclose(pose[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_array_equal(pose[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])
    # Pitch alone is Rot_y as in planar_transforms.
    np.testing.assert_allclose(
        pose_from_xyz_rpy([0, 0, 0.03], [0, 0.4, 0]), planar_transforms([0.4], 0.03)[0], atol=1e-16
    )


def test_pose_from_xyz_rpy_batches():
    rpy = np.random.default_rng(1).uniform(-3, 3, (5, 3))
    poses = pose_from_xyz_rpy(np.zeros(3), rpy)
    assert poses.shape == (5, 4, 4)
    check_rigid_motion(poses)
    for k in range(5):
        np.testing.assert_allclose(poses[k], pose_from_xyz_rpy([0, 0, 0], rpy[k]))


@pytest.mark.parametrize(
    ("matrix", "message"),
    [
        (np.eye(3), "shape"),
        (np.diag([1.0, 1.0, 2.0, 1.0]), "not orthonormal"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "det"),
        (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.5, 1.0]]), "bottom row"),
        (np.full((4, 4), np.nan), "non-finite"),
    ],
)
def test_check_rigid_motion_says_what_is_wrong(matrix, message):
    with pytest.raises(ValueError, match=message):
        check_rigid_motion(matrix)


def test_check_rigid_motion_names_batch_index_and_accepts_good():
    batch = np.broadcast_to(np.eye(4), (3, 4, 4)).copy()
    check_rigid_motion(batch)
    batch[2, 0, 0] = 1.01
    with pytest.raises(ValueError, match=r"index \(2,\)"):
        check_rigid_motion(batch)
    check_rigid_motion(pose_from_xyz_rpy([0.1, 0, 0], [0.3, 0.2, 0.1]) + 1e-8)  # within atol


def test_planar_transforms_shapes():
    angles = np.zeros((7, 2, 5))
    t = planar_transforms(angles, np.arange(1, 6) * 0.01)
    assert t.shape == (7, 2, 5, 4, 4)
    np.testing.assert_allclose(t[3, 1, :, 2, 3], np.arange(1, 6) * 0.01)


# ---------------------------------------------------------------- random links for properties

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


@st.composite
def links(draw, min_joints=1, max_joints=6):
    n = draw(st.integers(min_joints, max_joints))
    xyz = np.array(draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n))) * 0.05
    rpy = np.array(draw(st.lists(st.tuples(angle, angle, angle), min_size=n, max_size=n)))
    point = np.array(draw(st.tuples(finite, finite, finite))) * 0.05
    force = np.array(draw(st.tuples(finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-3))) * 10
    return pose_from_xyz_rpy(xyz, rpy), point, force


@settings(max_examples=60, deadline=None)
@given(link=links(), motion=st.tuples(finite, finite, finite, angle, angle, angle))
def test_rigid_motion_of_link_and_load_keeps_joint_moments(link, motion):
    transforms, point, force = link
    h = pose_from_xyz_rpy(np.array(motion[:3]) * 0.2, motion[3:])
    moved = transforms.copy()
    moved[0] = h @ transforms[0]
    moved_force = h[:3, :3] @ force
    before = joint_moment_norms(transforms, point, force)
    after = joint_moment_norms(moved, point, moved_force)
    scale = float(np.linalg.norm(force))  # moments are at most ~|F| x (link size < 1 m)
    np.testing.assert_allclose(after[1:], before[1:], rtol=1e-9, atol=1e-12 * scale)
    # A pure rotation about the base origin keeps the base moment too.
    rotated = transforms.copy()
    rotated[0, :3, :] = h[:3, :3] @ transforms[0, :3, :]
    np.testing.assert_allclose(
        joint_moment_norms(rotated, point, moved_force), before, rtol=1e-9, atol=1e-12 * scale
    )


@settings(max_examples=60, deadline=None)
@given(link=links(), scale=st.floats(-50.0, 50.0), other=st.tuples(finite, finite, finite))
def test_moments_are_linear_in_the_load(link, scale, other):
    transforms, point, force = link
    other_force = np.array(other) * 5
    base = joint_moments_recursive(transforms, point, force)
    np.testing.assert_allclose(
        joint_moments_recursive(transforms, point, scale * force), scale * base, rtol=1e-9, atol=1e-12
    )
    summed = joint_moments_recursive(transforms, point, force + other_force)
    parts = base + joint_moments_recursive(transforms, point, other_force)
    np.testing.assert_allclose(summed, parts, rtol=1e-9, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(link=links())
def test_recursion_equals_frame_free_form(link):
    transforms, point, force = link
    recursive = joint_moments_recursive(transforms, point, force)
    frame_free = joint_moments_frame_free(transforms, point, force)
    rotations = forward_kinematics(transforms)[..., :3, :3]
    in_world = np.einsum("ijk,ik->ij", rotations, recursive)
    np.testing.assert_allclose(in_world, frame_free, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(
        np.linalg.norm(recursive, axis=-1),
        joint_moment_norms(transforms, point, force),
        rtol=1e-9,
        atol=1e-13,
    )


@settings(max_examples=80, deadline=None)
@given(link=links(), capacities=st.lists(st.floats(0.05, 5.0), min_size=6, max_size=6))
def test_slip_force_puts_one_joint_on_its_capacity_and_none_above(link, capacities):
    transforms, point, direction = link
    n = transforms.shape[0]
    caps = np.array(capacities[:n])
    p = predict_slip(transforms, caps, point, direction)
    unit = direction / np.linalg.norm(direction)
    poses = forward_kinematics(transforms)
    distances = np.linalg.norm((poses[-1] @ np.append(point, 1.0))[:3] - poses[:, :3, 3], axis=-1)
    # An arm of a few ulps of the distance is known only to a few digits; such near-line cases are
    # covered by test_rounding_error_lever_arm_counts_as_on_the_load_line.
    arms = p.lever_arms_m
    assume(np.all((arms == 0) | (arms > 1e-6 * distances)))
    if int(p.first_slip_joint) == 0:
        assert np.isinf(p.slip_force_n)
        np.testing.assert_array_equal(p.lever_arms_m[1:], 0.0)
        return
    force = float(p.slip_force_n) * unit
    utilisation = joint_moment_norms(transforms, point, force)[1:] / caps
    assert np.max(utilisation) == pytest.approx(1.0, rel=1e-9)
    # The joint named first is on its capacity (several may be, within rounding: ties are not exact).
    assert utilisation[int(p.first_slip_joint) - 1] == pytest.approx(1.0, rel=1e-9)
    np.testing.assert_allclose(utilisation[p.tied_joints], 1.0, rtol=1e-9)
    assert np.all(utilisation[~p.tied_joints] < 1.0 + 1e-9)
    assert tolerated(transforms, caps, point, force)
    assert not tolerated(transforms, caps, point, force * (1 + 1e-6))
    assert float(p.tip_moment_nm) == pytest.approx(float(p.slip_force_n) * p.lever_arms_m[-1], rel=1e-12)
    assert float(p.slip_mass_kg) == pytest.approx(float(p.slip_force_n) / 9.8, rel=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_joints=st.integers(1, 8))
def test_batch_equals_per_configuration(seed, n_joints):
    rng = np.random.default_rng(seed)
    batch = (4, 3)
    transforms = pose_from_xyz_rpy(
        rng.uniform(-0.05, 0.05, (*batch, n_joints, 3)), rng.uniform(-3, 3, (*batch, n_joints, 3))
    )
    caps = rng.uniform(0.1, 3.0, (*batch, n_joints))
    points = rng.uniform(-0.05, 0.05, (*batch, 3))
    directions = rng.normal(size=(*batch, 3))
    p = predict_slip(transforms, caps, points, directions, g=9.81)
    norms = joint_moment_norms(transforms, points, directions)
    recursive = joint_moments_recursive(transforms, points, directions)
    allowed = tolerated(transforms, caps, points, directions)
    assert p.slip_force_n.shape == batch and p.lever_arms_m.shape == (*batch, n_joints + 1)
    for idx in np.ndindex(*batch):
        one = predict_slip(transforms[idx], caps[idx], points[idx], directions[idx], g=9.81)
        assert p.slip_force_n[idx] == pytest.approx(float(one.slip_force_n), rel=1e-12)
        assert p.slip_mass_kg[idx] == pytest.approx(float(one.slip_mass_kg), rel=1e-12)
        assert p.first_slip_joint[idx] == int(one.first_slip_joint)
        assert p.tip_moment_nm[idx] == pytest.approx(float(one.tip_moment_nm), rel=1e-12)
        assert p.base_moment_nm[idx] == pytest.approx(float(one.base_moment_nm), rel=1e-12)
        np.testing.assert_allclose(p.joint_moments_at_slip_nm[idx], one.joint_moments_at_slip_nm, rtol=1e-12)
        np.testing.assert_allclose(
            norms[idx], joint_moment_norms(transforms[idx], points[idx], directions[idx])
        )
        np.testing.assert_allclose(
            recursive[idx], joint_moments_recursive(transforms[idx], points[idx], directions[idx]), atol=1e-15
        )
        assert allowed[idx] == tolerated(transforms[idx], caps[idx], points[idx], directions[idx])


def test_a_batch_of_loads_broadcasts_against_one_link():
    transforms = vector_4_transforms()
    points = np.array([[0.0, 0.0, 0.03], [0.0, 0.0, 0.0], [0.01, 0.0, 0.02]])
    directions = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])[:, None, :]
    p = predict_slip(transforms, [2.0, 0.9, 0.8], points, directions)
    assert p.slip_force_n.shape == (2, 3)
    assert float(p.slip_force_n[0, 0]) == pytest.approx(15.231399, rel=REL)
    for i in range(2):
        for j in range(3):
            one = predict_slip(transforms, [2.0, 0.9, 0.8], points[j], directions[i, 0])
            assert p.slip_force_n[i, j] == pytest.approx(float(one.slip_force_n), rel=1e-12)
    batched_configs = planar_transforms(np.radians([[0, 30, -20], [10, 10, 10]]), 0.03)
    norms = joint_moment_norms(batched_configs, Q_TIP, np.array([[0.0, -9.8, 0.0], [0.0, -19.6, 0.0]]))
    np.testing.assert_allclose(norms[0], [1.1493376, 0.8612269, 0.5790670, 0.2940000], rtol=REL)


# ---------------------------------------------------------------- ties, the load line, bad input


def test_exact_tie_goes_to_the_joint_nearest_the_base():
    straight = planar_transforms(np.zeros(3), 0.03)  # o_i at z = .03, .06, .09; Q at z = .12
    p = predict_slip(straight, [0.9, 0.6, 0.3], Q_TIP, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(p.lever_arms_m, [0.12, 0.09, 0.06, 0.03], rtol=1e-12)
    assert float(p.slip_force_n) == pytest.approx(10.0, rel=1e-12)
    assert int(p.first_slip_joint) == 1
    np.testing.assert_array_equal(p.tied_joints, [True, True, True])


def test_joint_on_the_load_line_holds_any_load():
    transforms = np.stack([np.eye(4), np.eye(4)])
    transforms[0, 0, 3] = 0.05
    transforms[1, 2, 3] = 0.05  # o_1 = (.05, 0, 0), o_2 = (.05, 0, .05) = Q_w
    p = predict_slip(transforms, [1.0, 1e-6], [0, 0, 0], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(p.lever_arms_m, [0.05, 0.05, 0.0], atol=1e-15)
    assert float(p.slip_force_n) == pytest.approx(20.0)
    assert int(p.first_slip_joint) == 1
    assert p.joint_moments_at_slip_nm[2] == 0.0 and float(p.tip_moment_nm) == 0.0


def test_rounding_error_lever_arm_counts_as_on_the_load_line():
    # Q = (0, .0375, .05) is parallel to u = (0, .6, .8): the cross product is ~1e-18, not 0.
    t = np.eye(4)[None]
    p = predict_slip(t, [1.0], [0.0, 0.0375, 0.05], [0.0, 7.5, 10.0])
    np.testing.assert_array_equal(p.lever_arms_m, [0.0, 0.0])
    assert int(p.first_slip_joint) == 0
    # Just off the line, it is a (long) lever arm again.
    p = predict_slip(t, [1.0], [0.0, 0.0375, 0.05], [0.0, 7.5, 10.0 + 1e-9])
    assert 0 < p.lever_arms_m[1] < 1e-9 and int(p.first_slip_joint) == 1


def test_all_joints_on_the_load_line_means_nothing_slips():
    straight = planar_transforms(np.zeros(3), 0.03)
    p = predict_slip(straight, [0.9, 0.6, 0.3], Q_TIP, [0.0, 0.0, -1.0])
    assert np.isinf(p.slip_force_n) and np.isinf(p.slip_mass_kg)
    assert int(p.first_slip_joint) == 0
    assert not np.any(p.tied_joints)
    np.testing.assert_array_equal(p.joint_moments_at_slip_nm, 0.0)


def test_bad_inputs_raise_value_error():
    t = vector_4_transforms()
    with pytest.raises(ValueError, match="zero"):
        lever_arms_m(t, Q_TIP, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="zero"):
        predict_slip(t, [1, 1, 1], Q_TIP, [[0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        predict_slip(t, [1, 1], Q_TIP, DOWN)
    with pytest.raises(ValueError, match="> 0"):
        predict_slip(t, [1, 0, 1], Q_TIP, DOWN)
    with pytest.raises(ValueError, match="g"):
        predict_slip(t, [1, 1, 1], Q_TIP, DOWN, g=0.0)
    with pytest.raises(ValueError, match="shape"):
        forward_kinematics(np.eye(4))
    with pytest.raises(ValueError, match="point_m"):
        joint_moment_norms(t, [0, 0], DOWN)


def test_infinite_capacity_is_a_joint_that_never_slips():
    p = predict_slip(vector_4_transforms(), [np.inf, 0.9, np.inf], Q_TIP, DOWN)
    assert int(p.first_slip_joint) == 2
    assert float(p.slip_force_n) == pytest.approx(15.231399, rel=REL)


def test_a_joint_a_few_ulps_from_the_load_point_holds_no_moment():
    """Found by hypothesis: the load point 2.45e-150 m from the last joint, the others 0.05 m away on
    the load's line up to a 1e-16 tilt. Every arm is rounding error against the link's size, so
    nothing slips (before: the last joint's 2.45e-150 m arm gave a slip load of 4e149 N, which put
    the other joints at 4.5e132 times their capacity)."""
    transforms = np.stack([np.eye(4)] * 4)
    transforms[3, 1, 3] = 0.05
    p = predict_slip(transforms, [1.0] * 4, [0.0, 0.0, 2.452837e-150], [0.0, 10.0, 2.22044605e-15])
    np.testing.assert_array_equal(p.lever_arms_m, 0.0)
    assert int(p.first_slip_joint) == 0 and np.isinf(p.slip_force_n)
