"""The link in 3D: frames that reproduce the model's kinematics, the scene's marks, and the logged topics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from model.chain import forward_kinematics, planar_transforms
from rig.log.format import schemas
from rig.log.format.link_scene import (
    BASE_FRAME,
    WORLD_FRAME,
    LinkGeometry,
    LinkScene,
    _arrow_orientation,
    joint_frame,
    quaternion,
)

GEOMETRY = LinkGeometry((0.03, 0.04, 0.03, 0.05), 0.01, (0.0, 0.0, 0.03), (0.0, -1.0, 0.0))
ANGLES = (0.3, -0.2, 0.15, -0.4)


def _matrix(q: dict[str, float]) -> np.ndarray:
    return Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix()


def _scene(**changes: object) -> LinkScene:
    fields: dict[str, object] = {
        "geometry": GEOMETRY,
        "time_ns": 1_767_225_600_000_000_000,
        "trial_id": 4,
        "joint_angles_rad": ANGLES,
        "tension_n": 20.0,
    }
    fields.update(changes)
    return LinkScene(**fields)  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", range(20))
def test_quaternion_matches_scipy_for_any_rotation(seed: int) -> None:
    matrix = Rotation.random(random_state=seed).as_matrix()
    q = quaternion(matrix)
    assert q["w"] >= 0.0
    np.testing.assert_allclose(_matrix(q), matrix, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, math.pi, -math.pi / 2, 3.0])
def test_quaternion_of_half_turns_and_planar_joints(angle: float) -> None:
    matrix = Rotation.from_euler("y", angle).as_matrix()
    np.testing.assert_allclose(_matrix(quaternion(matrix)), matrix, atol=1e-12)


def test_frames_chain_reproduces_the_models_forward_kinematics() -> None:
    payload = _scene().frames_payload()
    by_child = {t["child_frame_id"]: t for t in payload["transforms"]}
    assert by_child[BASE_FRAME]["parent_frame_id"] == WORLD_FRAME
    # The world → base rotation turns the base's +y (up) into the viewer's +z.
    np.testing.assert_allclose(_matrix(by_child[BASE_FRAME]["rotation"]) @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    expected = forward_kinematics(
        planar_transforms(np.asarray(ANGLES), np.asarray(GEOMETRY.segment_lengths_m))
    )
    pose = np.eye(4)
    for joint in range(1, GEOMETRY.joint_count + 1):
        frame = by_child[joint_frame(joint)]
        assert frame["parent_frame_id"] == (BASE_FRAME if joint == 1 else joint_frame(joint - 1))
        step = np.eye(4)
        step[:3, :3] = _matrix(frame["rotation"])
        step[:3, 3] = [frame["translation"][k] for k in "xyz"]
        pose = pose @ step
        np.testing.assert_allclose(pose, expected[joint], atol=1e-12)


def test_scene_draws_a_sphere_per_joint_at_its_origin_and_the_segments() -> None:
    entity = _scene().scene_payload()["entities"][0]
    origins = forward_kinematics(
        planar_transforms(np.asarray(ANGLES), np.asarray(GEOMETRY.segment_lengths_m))
    )
    assert entity["frame_id"] == BASE_FRAME
    assert len(entity["spheres"]) == GEOMETRY.joint_count
    for joint, sphere in enumerate(entity["spheres"], start=1):
        centre = [sphere["pose"]["position"][k] for k in "xyz"]
        np.testing.assert_allclose(centre, origins[joint, :3, 3], atol=1e-12)
        assert sphere["size"]["x"] == pytest.approx(2 * GEOMETRY.joint_radius_m)
    points = entity["lines"][0]["points"]
    assert len(points) == GEOMETRY.joint_count + 1  # the base origin and every joint


def test_colours_mark_the_tested_and_the_slipped_joint() -> None:
    def colours(scene: LinkScene) -> list[tuple[float, ...]]:
        spheres = scene.scene_payload()["entities"][0]["spheres"]
        return [tuple(s["color"].values()) for s in spheres]

    quiet = colours(_scene(tested_joint=2, distance_m=0.05))
    assert len(set(quiet)) == 2 and quiet[1] != quiet[0]  # joint 2 differs, the rest alike
    slipped = colours(_scene(tested_joint=2, distance_m=0.05, slipped_joint=3, slipped=True))
    assert len({slipped[0], slipped[1], slipped[2]}) == 3  # grey, tested, slipped
    assert slipped[2][0] > 0.8 and slipped[2][1] < 0.3  # red
    unslipped = colours(_scene(slipped_joint=3, slipped=False))
    assert len(set(unslipped)) == 1


@pytest.mark.parametrize("direction", [(0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.3, 0.2, -0.9)])
def test_arrow_points_along_the_line(direction: tuple[float, float, float]) -> None:
    unit = np.asarray(direction) / np.linalg.norm(direction)
    np.testing.assert_allclose(_matrix(_arrow_orientation(unit)) @ [1, 0, 0], unit, atol=1e-12)


def test_joint_estimation_line_hangs_at_its_distance_from_the_tested_joint() -> None:
    straight = (0.0,) * GEOMETRY.joint_count
    scene = _scene(joint_angles_rad=straight, tested_joint=2, distance_m=0.1)
    arrow = scene.scene_payload()["entities"][0]["arrows"][0]
    tail = [arrow["pose"]["position"][k] for k in "xyz"]
    joint_2_z = sum(GEOMETRY.segment_lengths_m[:2])
    np.testing.assert_allclose(tail, [0.0, 0.0, joint_2_z + 0.1], atol=1e-12)


def _messages(log: Path, topic: str) -> list[tuple[int, dict]]:
    with log.open("rb") as stream:
        reader = make_reader(stream)
        return [(m.log_time, json.loads(m.data)) for _, ch, m in reader.iter_messages(topics=[topic])]


def test_a_run_logs_the_link_at_every_ramp_and_marks_each_slip(default_run_log: Path) -> None:
    frames = _messages(default_run_log, schemas.LINK_FRAMES)
    scenes = _messages(default_run_log, schemas.LINK_SCENE)
    results = [p for _, p in _messages(default_run_log, schemas.TRIAL_RESULT)]
    assert len(frames) == len(results) == 24  # one configuration per trial's ramp
    for _, payload in frames:
        children = [t["child_frame_id"] for t in payload["transforms"]]
        assert children == [BASE_FRAME] + [joint_frame(j) for j in range(1, 9)]
    # Every scene is stamped at its log time and after the frames it is drawn on.
    first_frame_ns = frames[0][0]
    for log_ns, payload in scenes:
        stamp = payload["entities"][0]["timestamp"]
        assert stamp["sec"] * 1_000_000_000 + stamp["nsec"] == log_ns
        assert log_ns >= first_frame_ns
    slipped = [p for _, p in scenes if "slip at joint" in p["entities"][0]["texts"][0]["text"]]
    slips = sum(1 for r in results if r["outcome"] == "slip")
    assert len(slipped) >= slips > 0
