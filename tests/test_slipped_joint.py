"""Which joint moved, from the configuration before and after a slip (model/slipped_joint.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from model.chain import planar_transforms
from model.slipped_joint import joint_rotations_rad, moved_joint, noise_threshold_rad


def test_the_joint_that_turned_most_is_named_above_the_threshold_only() -> None:
    before = planar_transforms(np.radians([5.0, -3.0, 2.0, 0.0]), 0.03)
    after = planar_transforms(np.radians([5.0, -3.0, 3.5, 0.1]), 0.03)
    assert joint_rotations_rad(before, after) == pytest.approx(np.radians([0.0, 0.0, 1.5, 0.1]), abs=1e-9)
    assert moved_joint(before, after, math.radians(0.5)) == 3
    assert moved_joint(before, after, math.radians(2.0)) is None


def test_a_rotation_out_of_the_plane_counts_by_its_angle() -> None:
    before = planar_transforms(np.zeros(3), 0.03)
    after = before.copy()
    c, s = math.cos(0.05), math.sin(0.05)
    after[1, :3, :3] = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # joint 2 about x
    assert moved_joint(before, after, 0.01) == 2


def test_mismatched_shapes_and_bad_thresholds_are_refused() -> None:
    with pytest.raises(ValueError, match="the same"):
        moved_joint(planar_transforms(np.zeros(3), 0.03), planar_transforms(np.zeros(4), 0.03), 0.1)
    with pytest.raises(ValueError, match="threshold_rad"):
        moved_joint(planar_transforms(np.zeros(3), 0.03), planar_transforms(np.zeros(3), 0.03), math.nan)


def test_the_noise_threshold_is_four_sd_of_a_difference_with_a_floor() -> None:
    assert noise_threshold_rad(None) == pytest.approx(math.radians(0.3))
    assert noise_threshold_rad(0.01) == pytest.approx(4 * math.sqrt(2) * 0.01)
