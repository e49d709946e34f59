"""Cross-check of `predict_slip` and `rig predict --json` against an independent implementation.

The reference below is written on purpose in a different style from `model/chain.py`: plain Python
floats and lists, one configuration at a time, rotations written out entry by entry, moments from
frame-free cross products `(Q_w - o_i) x F`. It imports nothing from `model/` or `rig/`.
"""

import json
import math
import random

import numpy as np
import pytest

from model.chain import joint_moment_norms, predict_slip

# ---------------------------------------------------------------- the independent reference


def ref_rotation(roll, pitch, yaw):
    """Rz(yaw) Ry(pitch) Rx(roll), multiplied out by hand."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def ref_matmul3(a, b):
    return [[sum(a[r][k] * b[k][c] for k in range(3)) for c in range(3)] for r in range(3)]


def ref_apply(a, v):
    return [a[r][0] * v[0] + a[r][1] * v[1] + a[r][2] * v[2] for r in range(3)]


def ref_cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def ref_norm(v):
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def ref_origins_and_point(joints, point):
    """Joint origins o_0..o_J and Q in the base frame; joints are (rotation, translation) pairs."""
    rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    origin = [0.0, 0.0, 0.0]
    origins = [origin]
    for joint_rotation, translation in joints:
        step = ref_apply(rotation, translation)
        origin = [origin[k] + step[k] for k in range(3)]
        origins.append(origin)
        rotation = ref_matmul3(rotation, joint_rotation)
    tip = ref_apply(rotation, point)
    return origins, [origin[k] + tip[k] for k in range(3)]


def ref_moment_norms(joints, point, force):
    origins, q = ref_origins_and_point(joints, point)
    return [ref_norm(ref_cross([q[k] - o[k] for k in range(3)], force)) for o in origins]


def ref_slip(joints, capacities, point, direction, g):
    length = ref_norm(direction)
    unit = [d / length for d in direction]
    arms = ref_moment_norms(joints, point, unit)
    best_force, best_joint = math.inf, 0
    for number, (arm, capacity) in enumerate(zip(arms[1:], capacities, strict=True), start=1):
        if arm > 0 and capacity / arm < best_force:
            best_force, best_joint = capacity / arm, number
    return {
        "slip_force_n": best_force,
        "slip_mass_kg": best_force / g,
        "first_slip_joint": best_joint,
        "tip_moment_nm": best_force * arms[-1],
        "base_moment_nm": best_force * arms[0],
        "joint_moments_nm": [best_force * a for a in arms[1:]],
        "arms": arms,
    }


# ---------------------------------------------------------------- random links


def random_link(rng):
    n = rng.randint(1, 10)
    joints, entries, capacities = [], [], []
    for _ in range(n):
        rpy = [rng.uniform(-math.pi, math.pi) for _ in range(3)]
        xyz = [rng.uniform(-0.05, 0.05) for _ in range(3)]
        rotation = ref_rotation(*rpy)
        joints.append((rotation, xyz))
        entry = {}
        if rng.random() < 0.5:
            entry["transform"] = [[*rotation[r], xyz[r]] for r in range(3)] + [[0.0, 0.0, 0.0, 1.0]]
        else:
            entry["xyz"], entry["rpy"] = xyz, rpy
        if rng.random() < 0.6:
            capacity = rng.uniform(0.2, 3.0)
            entry["capacity_nm"] = capacity
        else:
            radius, mu_delta0 = rng.uniform(0.005, 0.02), rng.uniform(5e4, 5e5)
            name = rng.choice(["paper", "derived"])
            entry.update(radius_m=radius, mu_delta0_pa=mu_delta0, constant=name)
            capacity = (5.4397 if name == "paper" else math.pi**2) * mu_delta0 * radius**3
        entries.append(entry)
        capacities.append(capacity)
    point = [rng.uniform(-0.05, 0.05) for _ in range(3)]
    load = [rng.gauss(0.0, 1.0) * 10 for _ in range(3)]
    return joints, entries, capacities, point, load


def as_arrays(joints):
    transforms = np.zeros((len(joints), 4, 4))
    for i, (rotation, xyz) in enumerate(joints):
        transforms[i, :3, :3] = rotation
        transforms[i, :3, 3] = xyz
        transforms[i, 3, 3] = 1.0
    return transforms


def close(actual, expected, scale):
    assert actual == pytest.approx(expected, rel=1e-9, abs=1e-12 * scale)


# ---------------------------------------------------------------- the checks


def test_reference_reproduces_model_vectors_5_and_7():
    joints = [(ref_rotation(0.0, math.radians(a), 0.0), [0.0, 0.0, 0.03]) for a in (0, 30, -20)]
    expected = [1.1493376, 0.8612269, 0.5790670, 0.2940000]
    assert ref_moment_norms(joints, [0, 0, 0.03], [0, -9.8, 0]) == pytest.approx(expected, rel=1e-6)
    slip = ref_slip(joints, [2.0, 0.9, 0.8], [0, 0, 0.03], [0, -1, 0], 9.8)
    assert slip["slip_force_n"] == pytest.approx(15.231399, rel=1e-6)
    assert slip["first_slip_joint"] == 2


@pytest.mark.parametrize("seed", range(40))
def test_predict_slip_agrees_with_reference(seed):
    rng = random.Random(seed)
    joints, _, capacities, point, direction = random_link(rng)
    g = rng.uniform(9.7, 9.9)
    ref = ref_slip(joints, capacities, point, direction, g)
    p = predict_slip(as_arrays(joints), capacities, point, direction, g=g)
    assert int(p.first_slip_joint) == ref["first_slip_joint"]
    for key in ("slip_force_n", "slip_mass_kg", "tip_moment_nm", "base_moment_nm"):
        close(float(getattr(p, key)), ref[key], ref["slip_force_n"])
    np.testing.assert_allclose(p.lever_arms_m, ref["arms"], rtol=1e-9, atol=1e-14)
    norms = joint_moment_norms(as_arrays(joints), point, direction)
    np.testing.assert_allclose(norms, ref_moment_norms(joints, point, direction), rtol=1e-9, atol=1e-13)


def test_batched_predict_slip_agrees_with_reference():
    n = 5
    rng = random.Random(7)
    configs = []
    for _ in range(50):
        joints = [(ref_rotation(*[rng.uniform(-3, 3) for _ in range(3)]), [0.0, 0.0, 0.03]) for _ in range(n)]
        configs.append(joints)
    transforms = np.stack([as_arrays(j) for j in configs])
    capacities = [0.5, 1.0, 1.5, 0.7, 0.9]
    p = predict_slip(transforms, capacities, [0.01, 0.0, 0.02], [0.0, 0.0, -1.0])
    for k, joints in enumerate(configs):
        ref = ref_slip(joints, capacities, [0.01, 0.0, 0.02], [0.0, 0.0, -1.0], 9.8)
        assert int(p.first_slip_joint[k]) == ref["first_slip_joint"]
        close(float(p.slip_force_n[k]), ref["slip_force_n"], ref["slip_force_n"])
        close(float(p.tip_moment_nm[k]), ref["tip_moment_nm"], ref["slip_force_n"])


def write_link(path, entries, point, load_key, load, g=None):
    data = {"joints": entries, "load": {"point_m": point, load_key: load}}
    if g is not None:
        data["g"] = g
    # JSON is YAML; repr-exact floats survive the round trip.
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("seed", range(20))
def test_rig_predict_json_agrees_with_reference(tmp_path, seed, cli_json):
    rng = random.Random(1000 + seed)
    joints, entries, capacities, point, load = random_link(rng)
    use_force = seed % 2 == 1
    g = 9.81 if seed % 3 == 0 else None
    path = write_link(
        tmp_path / "link.yaml", entries, point, "force_n" if use_force else "direction", load, g
    )
    out = cli_json("predict", path, "--json", quiet=True)
    assert set(out) == {
        "joint_moments_nm",
        "base_moment_nm",
        "slip_force_n",
        "slip_mass_kg",
        "first_slip_joint",
        "tip_moment_nm",
    }
    ref = ref_slip(joints, capacities, point, load, g or 9.8)
    scale = ref["slip_force_n"]
    assert out["first_slip_joint"] == ref["first_slip_joint"]
    close(out["slip_force_n"], ref["slip_force_n"], scale)
    close(out["slip_mass_kg"], ref["slip_mass_kg"], scale)
    close(out["tip_moment_nm"], ref["tip_moment_nm"], scale)
    if use_force:
        moments = ref_moment_norms(joints, point, load)
        scale = ref_norm(load)
        expected_joints, expected_base = moments[1:], moments[0]
    else:
        expected_joints, expected_base = ref["joint_moments_nm"], ref["base_moment_nm"]
    assert len(out["joint_moments_nm"]) == len(joints)
    for actual, expected in zip(out["joint_moments_nm"], expected_joints, strict=True):
        close(actual, expected, scale)
    close(out["base_moment_nm"], expected_base, scale)
