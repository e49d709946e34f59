"""Checks shared by the sources that take joint angles from a person or a file: count, range, finiteness."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from model.chain import planar_transforms

MAX_ABS_ANGLE_DEG = 90.0


def angle_problem(values_deg: Sequence[object], joint_count: int) -> str | None:
    """Why `values_deg` is not a configuration of `joint_count` joints, or None when it is one."""
    allowed = f"{joint_count} numbers in degrees, each in [-{MAX_ABS_ANGLE_DEG:g}, {MAX_ABS_ANGLE_DEG:g}]"
    if len(values_deg) != joint_count:
        return f"{len(values_deg)} angles; allowed: {allowed}"
    for i, value in enumerate(values_deg, start=1):
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            return f"joint {i}: {value!r} is not a number; allowed: {allowed}"
        if abs(value) > MAX_ABS_ANGLE_DEG:
            return f"joint {i}: {value:g} is out of range; allowed: {allowed}"
    return None


def planar_reading_transforms(angles_rad: Sequence[float], segment_lengths_m: Sequence[float]) -> np.ndarray:
    """The transforms of a planar configuration (rotations about y) on the rig's segment lengths."""
    return planar_transforms(np.asarray(angles_rad, dtype=float), np.asarray(segment_lengths_m, dtype=float))
