"""The camera configuration source on rendered images: joint angles within 0.5° RMS at the recommended
marker sizes (docs/formats.md §9.3) with blur, noise and partial occlusion; a hidden marker named;
calibration from rendered chessboard and ChArUco views recovers the intrinsics used to render them.

Needs OpenCV (the `camera` extra, installed by .ci/run); skipped, saying so, without it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

cv2 = pytest.importorskip(
    "cv2", reason="OpenCV is not installed: pip install -e '.[camera]' to run the camera tests"
)
if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "ArucoDetector"):  # pragma: no cover
    pytest.skip(
        f"OpenCV {cv2.__version__} has no cv2.aruco.ArucoDetector (needs >= 4.7)", allow_module_level=True
    )

from model.chain import planar_transforms, pose_from_xyz_rpy  # noqa: E402
from rig.cli import main  # noqa: E402
from rig.errors import InputError, NotConnectedError  # noqa: E402
from rig.hw.camera.camera_calibration import (  # noqa: E402
    Board,
    BoardKind,
    CameraCalibration,
    board_points,
    calibrate,
    calibrate_views,
    load_calibration,
    write_calibration,
)
from rig.hw.camera.marker_map import DICTIONARY_SIZES, load_marker_map  # noqa: E402
from rig.hw.camera.measure import MarkerDetector, MarkerNotSeenError, measure_image, rotation_error_rad  # noqa: E402
from rig.hw.camera.source import CameraConfigurationSource, CameraDevice, ImageFiles  # noqa: E402
from rig.hw.seams import ConfigurationReading, ConfigurationSource  # noqa: E402
from rig.testing.camera_images import (  # noqa: E402
    Rendering,
    SyntheticCamera,
    calibration_views,
    look_down_pose,
    marker_outline_px,
    render_link,
    tilted_view,
)
from rig.testing.camera_scenes import CONDITIONS, EXAMPLE_DEG, exact_calibration, random_scene  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
LINK1_MARKERS = ROOT / "protocols" / "link1_markers.yaml"
CAMERA = SyntheticCamera()  # 1280x960, fx = fy = 1000 px, mild barrel distortion
# The recommended range (docs/formats.md §9.3): 18 mm markers from 0.3 m (~60 px) to 0.4 m (~45 px).
DISTANCES_M = {"60px": 0.3, "45px": 0.4}
SIDES_PX = {"60px": (52, 68), "45px": (38, 50)}
SCENES = 6


@pytest.fixture(scope="module")
def marker_map():
    return load_marker_map(LINK1_MARKERS)


@pytest.fixture(scope="module")
def detector(marker_map):
    return MarkerDetector(marker_map, exact_calibration(CAMERA))


@pytest.fixture(scope="module")
def example_png(tmp_path_factory, marker_map):
    """The issue's hand-bent configuration at 0.3 m, written as a PNG."""
    transforms = planar_transforms(np.radians(EXAMPLE_DEG), marker_map.segment_lengths_m)
    scene = random_scene(marker_map, CAMERA, 0.3, seed=11, transforms=transforms)
    path = tmp_path_factory.mktemp("camera") / "example.png"
    assert cv2.imwrite(str(path), scene.image)
    return path


@pytest.fixture(scope="module")
def calibration_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("camera") / "cal.yaml"
    write_calibration(exact_calibration(CAMERA), path, overwrite=False)
    return path


def test_dictionary_sizes_match_opencv():
    for name, size in DICTIONARY_SIZES.items():
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        assert dictionary.bytesList.shape[0] == size, name


@pytest.mark.slow
@pytest.mark.parametrize("size", list(DISTANCES_M))
def test_joint_angles_within_half_a_degree_rms_with_blur_noise_and_occlusion(marker_map, detector, size):
    errors, z_scores = [], []
    for seed in range(SCENES):
        scene = random_scene(marker_map, CAMERA, DISTANCES_M[size], seed)
        measured = measure_image(detector, scene.image, source=f"scene {seed}", time_ns=0)
        lo, hi = SIDES_PX[size]
        assert all(lo <= m.side_px <= hi for m in measured.markers), [m.side_px for m in measured.markers]
        assert measured.planar
        error = measured.planar_angles_rad - scene.angles_rad
        errors.extend(error)
        z_scores.extend(error / measured.planar_angle_sd_rad)
    rms_deg = math.degrees(float(np.sqrt(np.mean(np.square(errors)))))
    assert rms_deg < 0.5, f"{size}: {rms_deg:.3f}° RMS over {len(errors)} joints"
    # the per-joint sd is of the right size: neither a fraction nor a multiple of the actual errors
    rms_z = float(np.sqrt(np.mean(np.square(z_scores))))
    assert 0.3 < rms_z < 2.0, rms_z


@pytest.mark.slow
def test_an_out_of_plane_joint_is_measured_in_3d_and_the_link_is_not_called_planar(marker_map, detector):
    rpy = [(0.0, a, 0.0) for a in np.radians([5, -10, 8, 0, 12, -6, 4, -9])]
    rpy[3] = (math.radians(12.0), math.radians(-8.0), 0.0)  # joint 4 tilted 12° out of the bending plane
    transforms = np.stack([pose_from_xyz_rpy([0, 0, 0.03], r) for r in rpy])
    scene = random_scene(marker_map, CAMERA, 0.3, seed=3, transforms=transforms, occlude=False)
    measured = measure_image(detector, scene.image, source="tilted", time_ns=0)
    assert not measured.planar
    assert measured.reading().joint_angles_rad is None
    assert math.degrees(measured.out_of_plane_rad[3]) == pytest.approx(12.0, abs=2.0)
    errors = [
        rotation_error_rad(m, t[:3, :3]) for m, t in zip(measured.joint_rotations, transforms, strict=True)
    ]
    assert math.degrees(float(np.sqrt(np.mean(np.square(errors))))) < 1.5
    np.testing.assert_allclose(measured.transforms[:, :3, 3], transforms[:, :3, 3])


def test_a_hidden_marker_is_an_error_naming_its_component(marker_map, detector):
    transforms = planar_transforms(np.radians(EXAMPLE_DEG), marker_map.segment_lengths_m)
    pose = look_down_pose(0.3, (0.0, 0.012, 0.13))
    outline = marker_outline_px(marker_map, transforms, pose, CAMERA, 5)
    hand = (outline - outline.mean(axis=0)) * 1.3 + outline.mean(axis=0)  # a finger over marker 5
    image = render_link(
        marker_map, transforms, pose, CAMERA, Rendering(noise_sigma=2.0, occluders=((hand, 0.6),))
    )
    with pytest.raises(MarkerNotSeenError) as exc:
        measure_image(detector, image, source="hand.png", time_ns=0)
    message = str(exc.value)
    assert message.startswith("hand.png: marker not seen for component 5 (component 5, marker 5)")
    assert "markers seen: [0, 1, 2, 3, 4, 6, 7, 8]" in message


def test_an_image_of_another_size_than_the_calibration_is_refused(marker_map):
    small = CameraCalibration(
        640, 480, np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.zeros(5), 0.0
    )
    detector = MarkerDetector(marker_map, small)
    with pytest.raises(
        InputError, match=r"^x.png: 1280x960 px; allowed: the calibration's image size 640x480"
    ):
        measure_image(detector, np.zeros((960, 1280), np.uint8), source="x.png", time_ns=0)


def test_the_camera_source_implements_the_seam(marker_map, example_png, calibration_file):
    source = CameraConfigurationSource(
        ImageFiles([example_png]), load_calibration(calibration_file), marker_map
    )
    assert isinstance(source, ConfigurationSource)
    reading = source.measure()
    assert isinstance(reading, ConfigurationReading)
    assert reading.joint_angles_rad is not None
    np.testing.assert_allclose(np.degrees(reading.joint_angles_rad), EXAMPLE_DEG, atol=0.6)
    truth = planar_transforms(np.radians(EXAMPLE_DEG), marker_map.segment_lengths_m)
    np.testing.assert_allclose(reading.transforms[:, :3, 3], truth[:, :3, 3])
    for measured, true in zip(reading.transforms, truth, strict=True):  # tilts are measured less well
        assert math.degrees(rotation_error_rad(measured[:3, :3], true[:3, :3])) < 3.0
    with pytest.raises(InputError, match="all 1 were measured"):
        source.measure()


def test_config_measure_prints_angles_and_json(capsys, example_png, calibration_file):
    args = [
        "config",
        "measure",
        str(example_png),
        "--camera",
        str(calibration_file),
        "--markers",
        str(LINK1_MARKERS),
    ]
    assert main(args) == 0
    table = capsys.readouterr().out
    assert f"{example_png}: planar" in table and "joint  angle [deg]" in table
    assert main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    (measurement,) = result["measurements"]
    np.testing.assert_allclose(measurement["joint_angles_deg"], EXAMPLE_DEG, atol=0.6)
    assert len(measurement["joint_angle_sd_rad"]) == 8 and min(measurement["joint_angle_sd_rad"]) > 0
    assert [m["marker_id"] for m in measurement["markers"]] == list(range(9))


def test_config_measure_of_an_image_missing_a_marker_exits_1_naming_it(
    tmp_path, capsys, marker_map, calibration_file
):
    path = _no_tip_png(tmp_path, marker_map)
    code = main(
        ["config", "measure", str(path), "--camera", str(calibration_file), "--markers", str(LINK1_MARKERS)]
    )
    captured = capsys.readouterr()
    assert code == 1 and captured.out == ""
    assert "tip (component 8, marker 8)" in captured.err and captured.err.count("\n") == 1


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace("camera_matrix", "camera_matriks"), "camera_matrix: required field is missing"),
        (lambda t: "camera_matrix: [1, 2]\n", "not OpenCV FileStorage YAML"),
        (
            lambda t: (
                t.replace("rows: 5", "rows: 3")
                .replace(", 0. ]", " ]")
                .replace("0.00050000000000000001, ", "")
            ),
            "distortion_coefficients",
        ),
        (lambda t: t.replace("image_width: 1280", "image_width: 100"), "camera_matrix: not a pinhole matrix"),
        (
            lambda t: t.replace("distortion_coefficients", "dist_coeffs"),
            "distortion_coefficients: required field is missing (the file has dist_coeffs",
        ),
    ],
    ids=["missing matrix", "not FileStorage", "distortion count", "principal point outside", "other key"],
)
def test_a_bad_calibration_file_exits_2_naming_the_field(
    tmp_path, capsys, calibration_file, example_png, edit, message
):
    bad = tmp_path / "bad.yaml"
    bad.write_text(edit(calibration_file.read_text()))
    code = main(
        ["config", "measure", str(example_png), "--camera", str(bad), "--markers", str(LINK1_MARKERS)]
    )
    err = capsys.readouterr().err
    assert code == 2, err
    assert str(bad) in err and message in err and err.count("\n") == 1


def _board_views(
    board: Board, camera: SyntheticCamera, count: int, seed: int
) -> list[tuple[str, np.ndarray]]:
    return [(f"view{i}", image) for i, image in enumerate(calibration_views(board, camera, count, seed=seed))]


SMALL_CAMERA = SyntheticCamera(640, 480, 610.0, 605.0, 325.5, 236.0, (-0.12, 0.08, 0.0, 0.0, 0.0))


@pytest.mark.slow
@pytest.mark.parametrize(
    "board",
    [Board(BoardKind.CHESSBOARD, 9, 6, 0.02), Board(BoardKind.CHARUCO, 7, 5, 0.025, 0.018, "DICT_5X5_100")],
    ids=["chessboard", "charuco"],
)
def test_calibration_recovers_the_rendering_intrinsics(tmp_path, board):
    result = calibrate(board, _board_views(board, SMALL_CAMERA, 12, seed=2))
    cal = result.calibration
    assert cal.views == 12 and not result.skipped
    assert cal.reprojection_error_px < 0.2
    assert cal.fx_px == pytest.approx(SMALL_CAMERA.fx_px, rel=0.006)
    assert cal.fy_px == pytest.approx(SMALL_CAMERA.fy_px, rel=0.006)
    cx, cy = cal.principal_point_px
    assert abs(cx - SMALL_CAMERA.cx_px) < 0.01 * SMALL_CAMERA.width
    assert abs(cy - SMALL_CAMERA.cy_px) < 0.01 * SMALL_CAMERA.height
    # the distortion as a whole (its coefficients trade off): rays through the middle 80 % of the image,
    # projected by the calibrated model, land within 1 % of the image width of where they were rendered
    xs, ys = np.meshgrid(
        np.linspace(0.1, 0.9, 9) * SMALL_CAMERA.width, np.linspace(0.1, 0.9, 7) * SMALL_CAMERA.height
    )
    pixels = np.stack([xs.ravel(), ys.ravel()], axis=1)
    rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2), SMALL_CAMERA.matrix, SMALL_CAMERA.dist).reshape(
        -1, 2
    )
    points = np.concatenate([rays, np.ones((len(rays), 1))], axis=1)
    projected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), cal.camera_matrix, cal.distortion)
    assert np.abs(projected.reshape(-1, 2) - pixels).max() < 0.01 * SMALL_CAMERA.width
    path = tmp_path / "cal.yaml"
    write_calibration(cal, path, overwrite=False)
    again = load_calibration(path)
    np.testing.assert_allclose(again.camera_matrix, cal.camera_matrix)
    np.testing.assert_allclose(again.distortion, cal.distortion)
    assert (again.image_width, again.image_height, again.views) == (640, 480, 12)
    assert again.board == board.describe()


@pytest.mark.slow
def test_camera_calibrate_writes_once_and_refuses_bad_input(tmp_path, capsys):
    board = Board(BoardKind.CHESSBOARD, 9, 6, 0.02)
    paths = []
    for name, image in _board_views(board, SMALL_CAMERA, 4, seed=2):
        paths.append(tmp_path / f"{name}.png")
        cv2.imwrite(str(paths[-1]), image)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    out = tmp_path / "cal.yaml"
    args = [
        "camera",
        "calibrate",
        *map(str, paths),
        str(blank),
        "--board",
        "chessboard",
        "--columns",
        "9",
        "--rows",
        "6",
        "--square-m",
        "0.02",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert f"wrote {out}" in captured.out and f"skipped (board not found): {blank}" in captured.err
    assert load_calibration(out).views == 4
    before = out.read_bytes()
    assert main(args) == 2  # an existing file is not replaced without --force
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before
    assert main([*args, "--force", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["skipped"] == [str(blank)] and result["dropped"] == []
    assert [v["image"] for v in result["views"]] == list(map(str, paths))  # each view's fit, in order
    assert all(0 < v["rms_px"] <= v["max_px"] < 1.0 and not v["dropped"] for v in result["views"])
    assert result["with_dropped_views"] is None
    # the board in too few images: exit 2, nothing written
    other = tmp_path / "other.yaml"
    few = [
        "camera",
        "calibrate",
        str(paths[0]),
        str(blank),
        "--board",
        "chessboard",
        "--columns",
        "9",
        "--rows",
        "6",
        "--square-m",
        "0.02",
        "--out",
        str(other),
    ]
    assert main(few) == 2
    assert "found in 1 of 2 images" in capsys.readouterr().err and not other.exists()
    wrong = [*few[:-2], "--columns", "8", "--out", str(other)]
    assert main(wrong) == 2 and not other.exists()


def test_a_camera_device_index_out_of_range_or_absent_is_a_clear_error():
    with pytest.raises(InputError, match="camera device index 64; allowed: 0 to 63"):
        CameraDevice(64)
    if Path("/dev/video63").exists():  # pragma: no cover
        pytest.skip("a camera is at index 63 here")
    with pytest.raises(NotConnectedError, match="camera 63: cannot be opened"):
        CameraDevice(63)


def test_an_unreadable_image_is_refused_naming_it(tmp_path, capsys, calibration_file):
    fake = tmp_path / "fake.png"
    fake.write_text("not an image")
    code = main(
        ["config", "measure", str(fake), "--camera", str(calibration_file), "--markers", str(LINK1_MARKERS)]
    )
    err = capsys.readouterr().err
    assert code == 2 and f"{fake}: not an image OpenCV can decode" in err


@pytest.mark.slow
def test_choosing_poses_along_the_chain_beats_each_markers_best_reprojection(marker_map, detector):
    # 35 px markers: the two IPPE solutions of a marker often reproject within a fraction of a pixel
    planar = {True: [], False: []}
    rotation = {True: [], False: []}
    for seed in range(6):
        scene = random_scene(marker_map, CAMERA, 0.5, 100 + seed, occlude=False)
        for along_chain in (True, False):
            measured = measure_image(detector, scene.image, source="x", time_ns=0, along_chain=along_chain)
            planar[along_chain].extend(measured.planar_angles_rad - scene.angles_rad)
            rotation[along_chain].extend(
                rotation_error_rad(m, t[:3, :3])
                for m, t in zip(measured.joint_rotations, scene.transforms, strict=True)
            )

    def rms(values):
        return float(np.sqrt(np.mean(np.square(values))))

    assert rms(rotation[True]) < 0.7 * rms(rotation[False])
    assert rms(planar[True]) <= rms(planar[False])


def _no_tip_png(tmp_path: Path, marker_map) -> Path:
    """The example configuration with the tip's marker off the link."""
    from dataclasses import replace

    transforms = planar_transforms(np.radians(EXAMPLE_DEG), marker_map.segment_lengths_m)
    image = render_link(
        replace(marker_map, components=marker_map.components[:-1]),
        transforms,
        look_down_pose(0.3, (0, 0.012, 0.13)),
        CAMERA,
        Rendering(),
    )
    path = tmp_path / "no-tip.png"
    cv2.imwrite(str(path), image)
    return path


def test_config_measure_measures_every_image_on_its_own(
    tmp_path, capsys, marker_map, example_png, calibration_file
):
    hidden = _no_tip_png(tmp_path, marker_map)
    garbage = tmp_path / "garbage.png"
    garbage.write_text("not an image")
    base = ["config", "measure", "--camera", str(calibration_file), "--markers", str(LINK1_MARKERS)]
    # one image whose marker is hidden between two good ones: both measured, exit 1 for the refused one
    assert main([*base, str(example_png), str(hidden), str(example_png)]) == 1
    captured = capsys.readouterr()
    assert captured.out.count(f"{example_png}: planar") == 2
    assert captured.err.count("\n") == 1 and f"{hidden}: marker not seen for tip" in captured.err
    assert main([*base, str(example_png), str(hidden), str(garbage), "--json"]) == 2  # invalid input wins
    result = json.loads(capsys.readouterr().out)
    first, second, third = result["measurements"]
    assert (result["measured"], result["refused"]) == (1, 2)
    np.testing.assert_allclose(first["joint_angles_deg"], EXAMPLE_DEG, atol=0.6)
    assert second["source"] == str(hidden) and second["error_type"] == "MarkerNotSeenError"
    assert "tip (component 8, marker 8)" in second["error"] and "joint_angles_deg" not in second
    assert third["error_type"] == "InputError" and "not an image OpenCV can decode" in third["error"]


@pytest.mark.slow
def test_a_bad_view_is_dropped_and_named_and_leaves_the_calibration_as_without_it():
    # 19 good views and one tilted 45° whose far corners were found off (the farthest row 2.3 px, as in
    # issue 32; a detector's bias on a foreshortened board)
    board = Board(BoardKind.CHESSBOARD, 9, 6, 0.02)
    images = [
        *calibration_views(board, SMALL_CAMERA, 19, seed=2),
        tilted_view(board, SMALL_CAMERA, math.radians(45.0), distance_m=0.35, blur_sigma_px=0.6),
    ]
    views = []
    for index, image in enumerate(images):
        found = board_points(board, image)
        assert found is not None
        views.append((f"view{index}", *found))
    name, obj, img = views[-1]
    far = obj[:, 1] / obj[:, 1].max()
    views[-1] = (name, obj, img + np.stack([np.zeros_like(far), 2.3 * far**4], axis=1).astype(np.float32))
    calibration, fits, threshold, with_dropped = calibrate_views(board.describe(), (640, 480), views)
    assert [f.image for f in fits if f.dropped] == ["view19"]
    assert fits[-1].rms_px > threshold and fits[-1].max_px > 0.5
    assert calibration.views == 19
    good, _, _, none_dropped = calibrate_views(board.describe(), (640, 480), views[:-1])
    assert none_dropped is None
    assert calibration.fx_px == pytest.approx(good.fx_px, rel=0.0005)  # the target: < 0.05 %
    assert with_dropped is not None and abs(with_dropped.fx_px / good.fx_px - 1) > 0.001  # it mattered


def test_markers_of_different_sizes_are_measured_each_at_its_own(tmp_path, detector):
    data = yaml.safe_load(LINK1_MARKERS.read_text())
    data["components"][0]["marker_length_m"] = 0.024  # the base's marker is larger than the others
    path = tmp_path / "mixed.yaml"
    path.write_text(yaml.safe_dump(data))
    mixed = load_marker_map(path)
    scene = random_scene(mixed, CAMERA, 0.3, seed=5, occlude=False)
    measured = measure_image(
        MarkerDetector(mixed, exact_calibration(CAMERA)), scene.image, source="x", time_ns=0
    )
    assert measured.markers[0].side_px > 1.25 * measured.markers[1].side_px
    assert np.abs(np.degrees(measured.planar_angles_rad - scene.angles_rad)).max() < 0.3
    assert measured.joint_gap_m[0] < 0.001  # the base's marker placed at its own size: joint 1 where it is


# issue 32's targets: every joint within 0.5° at >= 45 px on clean and moderately blurred images; on
# soft ones (blur σ 1.4 px, noise 4, contrast 0.6, a light gradient) RMS <= 0.3° and max <= 0.6° at >= 65 px
ACCURACY_TARGETS = {"clean": (0.4, 0.5, 0.5), "moderate": (0.4, 0.5, 0.5), "soft": (0.27, 0.3, 0.6)}


@pytest.mark.parametrize("condition", list(ACCURACY_TARGETS))
def test_joint_angles_meet_the_targets_on_sharp_and_soft_images(marker_map, detector, condition):
    distance_m, rms_max_deg, max_deg = ACCURACY_TARGETS[condition]
    errors, sides = [], []
    for seed in range(4):
        scene = random_scene(
            marker_map, CAMERA, distance_m, 200 + seed, occlude=False, condition=CONDITIONS[condition]
        )
        measured = measure_image(detector, scene.image, source=f"scene {seed}", time_ns=0)
        assert measured.planar
        errors.extend(np.degrees(measured.planar_angles_rad - scene.angles_rad))
        sides.extend(m.side_px for m in measured.markers)
    assert np.mean(sides) > (43 if condition != "soft" else 64), np.mean(sides)  # mean marker side [px]
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert rms <= rms_max_deg and np.abs(errors).max() <= max_deg, (rms, np.abs(errors).max())


def test_the_angle_sd_covers_the_errors_in_every_image_condition(marker_map, detector):
    # 96 joints at 50 px, 32 per condition: ~95 % within 2 sd if the sd is right
    z_scores = []
    for condition in CONDITIONS.values():
        for seed in range(4):
            scene = random_scene(marker_map, CAMERA, 0.35, 300 + seed, occlude=False, condition=condition)
            measured = measure_image(detector, scene.image, source=f"scene {seed}", time_ns=0)
            assert measured.planar, (condition.name, seed, measured.out_of_plane_statistic)
            z_scores.extend((measured.planar_angles_rad - scene.angles_rad) / measured.planar_angle_sd_rad)
    z = np.abs(z_scores)
    assert np.mean(z <= 2.0) >= 0.88 and 0.6 < np.sqrt(np.mean(z**2)) < 1.3, (
        np.mean(z <= 2),
        np.sqrt(np.mean(z**2)),
    )


def test_a_shaded_margin_on_a_soft_image_does_not_tilt_the_link_out_of_plane(marker_map, detector):
    # the tests' occlusions on soft images at 51 px: a dark strip over the outer half of a marker's white
    # margin, within the blur's reach, moves the whole edge out; seen as a tilt, these three were called
    # non-planar (out-of-plane statistics 24-40 against 23.03) before the sides' margin levels were compared
    for seed in (0, 3, 7):
        scene = random_scene(marker_map, CAMERA, 0.35, seed, condition=CONDITIONS["soft"])
        measured = measure_image(detector, scene.image, source=f"scene {seed}", time_ns=0)
        assert measured.planar, (seed, measured.out_of_plane_statistic)


def test_a_marker_whose_edges_cannot_be_fitted_is_refined_by_its_corners(monkeypatch, marker_map, detector):
    from rig.hw.camera.edges import EdgeRefiner

    monkeypatch.setattr(EdgeRefiner, "refine", lambda self, image, corners: None)  # every side hidden
    errors = []
    for seed in range(3):
        scene = random_scene(marker_map, CAMERA, 0.3, 400 + seed, occlude=False)
        measured = measure_image(detector, scene.image, source=f"scene {seed}", time_ns=0)
        errors.extend(np.degrees(measured.planar_angles_rad - scene.angles_rad))
    # ArUco's unrefined corners alone are up to a pixel out: 0.55° RMS here
    assert float(np.sqrt(np.mean(np.square(errors)))) < 0.3
