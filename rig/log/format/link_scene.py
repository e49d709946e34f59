"""The link in 3D for Foxglove and Lichtblick: each component's frame and the scene drawn on them.

Two topics, both with Foxglove's well-known schema names so that the 3D panel draws them without a
plugin (`rig.log.format.scene_schemas`):

* `/rig/link/frames` (`foxglove.FrameTransforms`): `world → base → joint_1 → … → joint_J`. The pose
  of `joint_i` in `joint_{i-1}` is the model's `T_i` (docs/model.md §1) at the trial's configuration,
  the measured one when the rig has a configuration source, else the commanded one. `world → base`
  turns the base frame's +y (up in the shipped rigs) into the viewer's +z.
* `/rig/link/scene` (`foxglove.SceneUpdate`): one entity `link`, drawn in `base`: a sphere per joint
  (grey; the joint under test blue; the joint that slipped red), the segments as a line strip, the
  line as an orange arrow at its attachment point along its pull direction whose length grows
  with the tension, and a text with the trial, the tension and the slip. Every field Foxglove's
  schema requires is there (the primitive lists it does not draw, empty).

A scene is a function of a `LinkScene` record: the geometry of the article, a configuration and
the state of the trial. No I/O; the runner logs the payloads (`rig.runner.link_view`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from model.chain import forward_kinematics, planar_transforms
from rig.records import stamp

WORLD_FRAME = "world"
BASE_FRAME = "base"
ENTITY_ID = "link"
# The arrow's length per newton of line tension, and its cap (the view, not the physics).
ARROW_M_PER_N = 0.004
ARROW_MAX_M = 0.25
ARROW_MIN_M = 0.03  # a slack line still shows where it is tied
_SEGMENT_WIDTH_M = 0.004

_GREY = {"r": 0.62, "g": 0.64, "b": 0.68, "a": 1.0}
_BLUE = {"r": 0.20, "g": 0.45, "b": 0.95, "a": 1.0}
_RED = {"r": 0.92, "g": 0.18, "b": 0.15, "a": 1.0}
_ORANGE = {"r": 0.98, "g": 0.60, "b": 0.10, "a": 1.0}
_WHITE = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}
_IDENTITY_ROTATION = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
# Rx(+90°): the base frame's +y becomes the world's +z.
_BASE_IN_WORLD = {"x": math.sqrt(0.5), "y": 0.0, "z": 0.0, "w": math.sqrt(0.5)}


def joint_frame(joint: int) -> str:
    """The frame id of joint `joint` (1-based)."""
    return f"joint_{joint}"


def quaternion(rotation: np.ndarray) -> dict[str, float]:
    """The unit quaternion (x, y, z, w) of a 3×3 rotation matrix, w ≥ 0."""
    r = np.asarray(rotation, dtype=float)
    trace = float(r[0, 0] + r[1, 1] + r[2, 2])
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (float(r[2, 1] - r[1, 2]) / s, float(r[0, 2] - r[2, 0]) / s, float(r[1, 0] - r[0, 1]) / s, s / 4)
    else:
        # Largest diagonal first keeps the square root away from zero.
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + float(r[i, i] - r[j, j] - r[k, k]), 0.0))
        v = [0.0, 0.0, 0.0]
        v[i] = s / 4
        v[j] = float(r[j, i] + r[i, j]) / s
        v[k] = float(r[k, i] + r[i, k]) / s
        q = (v[0], v[1], v[2], float(r[k, j] - r[j, k]) / s)
    if q[3] < 0.0:
        q = (-q[0], -q[1], -q[2], -q[3])
    return {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}


def _vector(v: Sequence[float] | np.ndarray) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _pose(
    position: Sequence[float] | np.ndarray, orientation: dict[str, float] | None = None
) -> dict[str, Any]:
    return {"position": _vector(position), "orientation": orientation or _IDENTITY_ROTATION}


@dataclass(frozen=True, slots=True)
class LinkGeometry:
    """What the view needs of the article: segment lengths, joint radius, and the line's attachment.

    `point_m` is the acting point Q in the tip frame and `direction` the line's pull in the base frame
    (the rig config's `article.load`); a joint-estimation trial hangs the line at `distance_m` from
    the tested joint's centre along the link instead.
    """

    segment_lengths_m: tuple[float, ...]
    joint_radius_m: float
    point_m: tuple[float, float, float]
    direction: tuple[float, float, float]

    @property
    def joint_count(self) -> int:
        return len(self.segment_lengths_m)


@dataclass(frozen=True, slots=True)
class LinkScene:
    """The link at one moment of a trial: its configuration and what the line is doing."""

    geometry: LinkGeometry
    time_ns: int
    trial_id: int
    joint_angles_rad: tuple[float, ...]  # measured, else commanded; zeros for a straight link
    tension_n: float
    tested_joint: int | None = None  # joint estimation: the joint under test
    distance_m: float | None = None  # joint estimation: where the line hangs from the tested joint
    slipped_joint: int | None = None  # 1-based, once known
    slipped: bool = False

    def _transforms(self) -> np.ndarray:
        """The model's T_1..T_J at this configuration (docs/model.md §1)."""
        return planar_transforms(
            np.asarray(self.joint_angles_rad, dtype=float), np.asarray(self.geometry.segment_lengths_m)
        )

    def frames_payload(self) -> dict[str, Any]:
        """The `foxglove.FrameTransforms` payload: world → base → joint_1 … joint_J."""
        when = stamp(self.time_ns)
        transforms = self._transforms()
        frames = [
            {
                "timestamp": when,
                "parent_frame_id": WORLD_FRAME,
                "child_frame_id": BASE_FRAME,
                "translation": _vector((0.0, 0.0, 0.0)),
                "rotation": _BASE_IN_WORLD,
            }
        ]
        for i in range(self.geometry.joint_count):
            parent = BASE_FRAME if i == 0 else joint_frame(i)
            frames.append(
                {
                    "timestamp": when,
                    "parent_frame_id": parent,
                    "child_frame_id": joint_frame(i + 1),
                    "translation": _vector(transforms[i, :3, 3]),
                    "rotation": quaternion(transforms[i, :3, :3]),
                }
            )
        return {"transforms": frames}

    def _attachment_m(self, poses: np.ndarray) -> np.ndarray:
        """Where the line is tied, in the base frame."""
        if self.tested_joint is not None and self.distance_m is not None:
            pose = poses[self.tested_joint]
            return np.asarray(pose[:3, 3] + pose[:3, 2] * self.distance_m)
        tip = poses[-1]
        return np.asarray(tip[:3, 3] + tip[:3, :3] @ np.asarray(self.geometry.point_m, dtype=float))

    def _joint_colour(self, joint: int) -> dict[str, float]:
        if self.slipped and joint == self.slipped_joint:
            return _RED
        if joint == self.tested_joint:
            return _BLUE
        return _GREY

    def _caption(self) -> str:
        text = f"trial {self.trial_id}: {self.tension_n:.1f} N"
        if self.slipped:
            where = f"joint {self.slipped_joint}" if self.slipped_joint is not None else "a joint"
            text += f", slip at {where}"
        return text

    def scene_payload(self) -> dict[str, Any]:
        """The `foxglove.SceneUpdate` payload: the entity `link` in the base frame, replacing the last."""
        when = stamp(self.time_ns)
        poses = forward_kinematics(self._transforms())
        origins = poses[:, :3, 3]
        diameter = 2.0 * self.geometry.joint_radius_m
        spheres = [
            {
                "pose": _pose(origins[j]),
                "size": _vector((diameter, diameter, diameter)),
                "color": self._joint_colour(j),
            }
            for j in range(1, self.geometry.joint_count + 1)
        ]
        segments = {
            "type": 0,  # LINE_STRIP
            "pose": _pose((0.0, 0.0, 0.0)),
            "thickness": _SEGMENT_WIDTH_M,
            "scale_invariant": False,
            "points": [_vector(o) for o in origins],
            "color": _GREY,
            "colors": [],
            "indices": [],
        }
        attachment = self._attachment_m(poses)
        direction = np.asarray(self.geometry.direction, dtype=float)
        direction = direction / float(np.linalg.norm(direction))
        length_m = min(ARROW_MAX_M, ARROW_MIN_M + max(self.tension_n, 0.0) * ARROW_M_PER_N)
        arrow = {
            "pose": _pose(attachment, _arrow_orientation(direction)),
            "shaft_length": 0.8 * length_m,
            "shaft_diameter": 0.003,
            "head_length": 0.2 * length_m,
            "head_diameter": 0.01,
            "color": _ORANGE,
        }
        label = {
            "pose": _pose(attachment + np.array([0.0, 0.03, 0.0])),
            "billboard": True,
            "font_size": 14.0,
            "scale_invariant": True,
            "color": _WHITE,
            "text": self._caption(),
        }
        entity = {
            "timestamp": when,
            "frame_id": BASE_FRAME,
            "id": ENTITY_ID,
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [],
            "arrows": [arrow],
            "cubes": [],
            "spheres": spheres,
            "cylinders": [],
            "lines": [segments],
            "triangles": [],
            "texts": [label],
            "models": [],
        }
        return {"deletions": [], "entities": [entity]}


def _arrow_orientation(direction: np.ndarray) -> dict[str, float]:
    """The rotation taking +x (a Foxglove arrow's axis) onto the unit vector `direction`."""
    x = np.array([1.0, 0.0, 0.0])
    axis = np.cross(x, direction)
    sin_angle = float(np.linalg.norm(axis))
    cos_angle = float(np.dot(x, direction))
    if sin_angle < 1e-12:
        # Along +x, or exactly against it (a half turn about z).
        return _IDENTITY_ROTATION if cos_angle > 0 else {"x": 0.0, "y": 0.0, "z": 1.0, "w": 0.0}
    half = math.atan2(sin_angle, cos_angle) / 2.0
    unit = axis / sin_angle
    s = math.sin(half)
    return {"x": float(unit[0] * s), "y": float(unit[1] * s), "z": float(unit[2] * s), "w": math.cos(half)}
