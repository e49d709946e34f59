"""Rendered scenes of a bent link for the camera tests and benchmark (needs OpenCV): see `random_scene`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from model.chain import forward_kinematics, planar_transforms
from rig.hw.camera.camera_calibration import CameraCalibration
from rig.hw.camera.marker_map import MarkerMap
from rig.testing.camera_images import (
    Rendering,
    SyntheticCamera,
    look_down_pose,
    marker_outline_px,
    render_link,
)

FloatArray = NDArray[np.float64]
# A hand-bent configuration of link 1 quoted in issue 23 (degrees).
EXAMPLE_DEG = (-11.1, 9.5, 7.1, 15.7, -16.5, -3.1, -18.8, -11.3)


@dataclass(frozen=True)
class ImageCondition:
    """How sharp and clean an image is: blur σ [px], noise σ [grey levels], contrast, light gradient."""

    name: str
    blur_sigma_px: float
    noise_sigma: float
    contrast: float = 1.0
    illumination_gradient: float = 0.0


# The conditions of issue 32. Moderate is the tests' own; soft is a webcam at the edge of its depth of
# field or a slightly misfocused lens: twice the blur and noise, ink 0.2 grey rather than black, paper
# 0.8 rather than white, and 30 % less light at one side of the image than at the other.
CLEAN = ImageCondition("clean", blur_sigma_px=0.0, noise_sigma=1.0)
MODERATE = ImageCondition("moderate", blur_sigma_px=0.7, noise_sigma=2.0)
SOFT = ImageCondition("soft", blur_sigma_px=1.4, noise_sigma=4.0, contrast=0.6, illumination_gradient=0.3)
CONDITIONS = {c.name: c for c in (CLEAN, MODERATE, SOFT)}


def exact_calibration(camera: SyntheticCamera) -> CameraCalibration:
    """The calibration a perfect `rig camera calibrate` would give for `camera`."""
    return CameraCalibration(camera.width, camera.height, camera.matrix, camera.dist, 0.0)


def quiet_zone_strip(corners: FloatArray, side: int, inner: float = 0.5, outer: float = 1.0) -> FloatArray:
    """A polygon over the white margin outside one edge of a marker, from `inner` to `outer` cells out."""
    a, b = corners[side], corners[(side + 1) % 4]
    cell = np.linalg.norm(b - a) / 6  # a 4x4 marker is 6 cells across with its border
    out = (a + b) / 2 - corners.mean(axis=0)
    out /= np.linalg.norm(out)
    return np.array(
        [a + out * inner * cell, b + out * inner * cell, b + out * outer * cell, a + out * outer * cell]
    )


def cell_blob(corners: FloatArray, u: int, v: int, fraction: float = 0.6) -> FloatArray:
    """A polygon over the middle `fraction` of bit cell (u, v) (0-5, border included) of a marker."""
    tl, tr, br, bl = corners

    def at(x: float, y: float) -> FloatArray:
        return np.asarray(tl + (tr - tl) * x + (bl - tl) * y + (br - tr - bl + tl) * x * y, np.float64)

    h, cx, cy = fraction / 12, (u + 0.5) / 6, (v + 0.5) / 6
    return np.array([at(cx - h, cy - h), at(cx + h, cy - h), at(cx + h, cy + h), at(cx - h, cy + h)])


@dataclass(frozen=True)
class Scene:
    """A rendered image and the configuration it shows."""

    angles_rad: FloatArray  # (J,) planar angles
    transforms: FloatArray  # (J, 4, 4)
    image: NDArray[np.uint8]


def random_scene(
    marker_map: MarkerMap,
    camera: SyntheticCamera,
    distance_m: float,
    seed: int,
    *,
    occlude: bool = True,
    transforms: FloatArray | None = None,
    max_angle_rad: float = math.radians(20.0),
    condition: ImageCondition = MODERATE,
    max_camera_tilt_rad: float = 0.14,
) -> Scene:
    """A link rendered bent within ±`max_angle_rad` per joint (or as `transforms`), with artefacts.

    Seen from `distance_m` above its middle by a camera tilted up to ±`max_camera_tilt_rad` (8°) about
    each of its axes, in `condition` (blur σ 0.7 px and noise σ 2 grey levels unless told) and, if
    `occlude`, with partial occlusions: the outer half of the white margin along one edge of three
    markers, and part of one inner bit cell of a fourth.
    """
    rng = np.random.default_rng(seed)
    joints = marker_map.joint_count
    if transforms is None:
        angles = rng.uniform(-max_angle_rad, max_angle_rad, joints)
        transforms = planar_transforms(angles, marker_map.segment_lengths_m)
    else:
        angles = np.arctan2(transforms[:, 0, 2], transforms[:, 2, 2])
    origins = forward_kinematics(transforms)[:, :3, 3]
    centre = (origins.min(axis=0) + origins.max(axis=0)) / 2 + np.array([0.0, 0.012, 0.0])
    tilt = rng.uniform(-max_camera_tilt_rad, max_camera_tilt_rad, 2)
    pose = look_down_pose(distance_m, centre, tilt_rad=(float(tilt[0]), float(tilt[1])))
    occluders: list[tuple[FloatArray, float]] = []
    if occlude and len(marker_map.components) >= 4:
        picked = rng.choice(len(marker_map.components), size=4, replace=False)
        for k in picked[:3]:
            outline = marker_outline_px(marker_map, transforms, pose, camera, int(k))
            occluders.append((quiet_zone_strip(outline, int(rng.integers(4))), float(rng.uniform(0.1, 0.4))))
        outline = marker_outline_px(marker_map, transforms, pose, camera, int(picked[3]))
        u, v = (int(x) for x in rng.integers(1, 5, 2))
        occluders.append((cell_blob(outline, u, v), float(rng.uniform(0.3, 0.7))))
    rendering = Rendering(
        blur_sigma_px=condition.blur_sigma_px,
        noise_sigma=condition.noise_sigma,
        contrast=condition.contrast,
        illumination_gradient=condition.illumination_gradient,
        occluders=tuple(occluders),
        seed=seed,
    )
    return Scene(angles, transforms, render_link(marker_map, transforms, pose, camera, rendering))
