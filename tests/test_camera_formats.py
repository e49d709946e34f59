"""The camera's files and command line without OpenCV: marker maps validated, a clear message when the
extra is missing, and the commands' help available either way."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from model.joint_rotation import joint_rotations, planar_projection, rot_y, rotation_angle_rad
from rig.cli import main
from rig.errors import ConfigError
from rig.hw.camera.marker_map import DICTIONARY_SIZES, CornerRefinement, load_marker_map

ROOT = Path(__file__).resolve().parent.parent
LINK1_MARKERS = ROOT / "protocols" / "link1_markers.yaml"


def test_the_shipped_link1_map_matches_the_link1_preset():
    from rig.sim.physics.link_presets import make_preset

    marker_map = load_marker_map(LINK1_MARKERS)
    preset = make_preset("link1", seed=0)
    assert marker_map.segment_lengths_m == preset.segment_lengths_m
    assert marker_map.joint_count == len(preset.segment_lengths_m) == 8
    assert [c.marker_id for c in marker_map.components] == list(range(9))
    assert marker_map.corner_refinement == CornerRefinement.EDGES
    # every marker faces up (+y of its component), printed x across the link
    for component in marker_map.components:
        rotation = component.pose_in_component[:3, :3]
        np.testing.assert_allclose(rotation[:, 2], [0, 1, 0], atol=1e-12)
        np.testing.assert_allclose(rotation[:, 0], [1, 0, 0], atol=1e-12)


def _write(tmp_path: Path, data: object) -> Path:
    path = tmp_path / "map.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _valid() -> dict:
    return yaml.safe_load(LINK1_MARKERS.read_text())


@pytest.mark.parametrize(
    ("change", "field", "allowed"),
    [
        (lambda d: d.update(dictionary="DICT_9X9_50"), "dictionary", "DICT_4X4_50"),
        (lambda d: d.update(marker_length_m=0.0), "marker_length_m", "0.002"),
        (lambda d: d["components"].pop(), "components", "one component per segment"),
        (lambda d: d["components"][3].update(marker_id=2), "components[3].marker_id", "one marker per id"),
        (lambda d: d["components"][1].update(marker_id=50), "components[1].marker_id", "49"),
        (lambda d: d["components"][2].pop("rpy_rad"), "components[2].rpy_rad", "missing"),
        (lambda d: d["components"][2].update(colour="red"), "components[2].colour", "unknown field"),
        (lambda d: d["components"][4].update(marker_length_m=0.6), "components[4].marker_length_m", "0.5"),
        (lambda d: d.update(planar_tolerance_rad=1.0), "planar_tolerance_rad", "0.5"),
        (lambda d: d.update(corner_refinement="best"), "corner_refinement", "subpix"),
        (lambda d: d.update(segment_lengths_m=[0.03] * 7 + [float("nan")]), "segment_lengths_m[7]", "1.0"),
    ],
)
def test_a_bad_marker_map_names_the_file_and_field(tmp_path, change, field, allowed):
    data = _valid()
    change(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError) as exc:
        load_marker_map(path)
    message = str(exc.value)
    assert message.startswith(f"{path}: {field}"), message
    assert allowed in message
    assert "\n" not in message


def test_a_component_may_give_its_own_marker_length(tmp_path):
    data = _valid()
    data["components"][0]["marker_length_m"] = 0.03  # a larger marker on the clamped base
    marker_map = load_marker_map(_write(tmp_path, data))
    assert [c.marker_length_m for c in marker_map.components] == [0.03] + [0.018] * 8
    assert marker_map.marker_length_m == 0.018


def test_dictionary_sizes_cover_the_named_dictionaries():
    assert DICTIONARY_SIZES["DICT_4X4_50"] == 50
    assert DICTIONARY_SIZES["DICT_APRILTAG_36H11"] == 587
    assert len(DICTIONARY_SIZES) == 22


def test_joint_rotations_and_planar_projection():
    rng = np.random.default_rng(0)
    angles = rng.uniform(-0.5, 0.5, 5)
    world = [np.eye(3)]
    for a in angles:
        world.append(world[-1] @ rot_y(a))
    # the same chain seen from any common frame gives the same joint rotations
    camera_from_world = rot_y(0.3) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    rotations = joint_rotations(np.stack([camera_from_world @ w for w in world]))
    planar, tilt = planar_projection(rotations)
    np.testing.assert_allclose(planar, angles, atol=1e-12)
    np.testing.assert_allclose(tilt, 0, atol=1e-12)
    # a twist about the joint's own axis is out of plane, and leaves the planar angle alone
    twist = np.array([[np.cos(0.1), -np.sin(0.1), 0], [np.sin(0.1), np.cos(0.1), 0], [0, 0, 1]])
    planar, tilt = planar_projection((rot_y(0.4) @ twist)[None])
    assert planar[0] == pytest.approx(0.4) and tilt[0] == pytest.approx(0.1)
    assert rotation_angle_rad(rot_y(np.pi - 1e-9)) == pytest.approx(np.pi - 1e-9)


@pytest.mark.parametrize(
    "argv",
    [
        ["config", "measure", "x.png", "--camera", "cal.yaml", "--markers", str(LINK1_MARKERS)],
        [
            "camera",
            "calibrate",
            "x.png",
            "--board",
            "chessboard",
            "--columns",
            "9",
            "--rows",
            "6",
            "--square-m",
            "0.025",
            "--out",
            "cal.yaml",
        ],
    ],
    ids=["config measure", "camera calibrate"],
)
def test_without_opencv_the_commands_exit_2_naming_the_extra(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.png").write_bytes(b"\x89PNG")
    (tmp_path / "cal.yaml").write_text("%YAML 1.2\n---\n")
    if argv[0] == "camera":
        (tmp_path / "cal.yaml").unlink()
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 now raises ImportError
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "pip install -e '.[camera]'" in err
    assert "Traceback" not in err and err.count("\n") == 1
    assert not (tmp_path / "cal.yaml").exists() or argv[0] == "config"


def test_rig_help_does_not_import_opencv(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "camera" in out and "config" in out
