"""Camera calibration: intrinsics from chessboard or ChArUco views, kept as OpenCV FileStorage YAML.

The file (docs/formats.md §9.1) holds `image_width`, `image_height`, `camera_matrix` (3×3),
`distortion_coefficients` (OpenCV's k1 k2 p1 p2 [k3 ...]) and `avg_reprojection_error` [px], the
names OpenCV's own calibration sample writes, plus how it was made (`board`, `views`). It is written
atomically (a temporary file renamed into place), so a reader never sees half of one. A view that
fits the calibration far worse than the others (`outlier_threshold_px`) is dropped and named.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rig.errors import InputError
from rig.hw.camera.marker_map import DICTIONARY_SIZES
from rig.hw.camera.opencv import require_cv2
from rig.inputs.files import atomic_write_text, read_text_file

IMAGE_SIDE_RANGE_PX = (16, 20000)
MIN_VIEWS = 3
# A view is an outlier when its RMS reprojection error is above both of these (`outlier_threshold_px`):
# on rendered views the good ones spread 0.025-0.19 px about a median of 0.06 px (tests/test_camera.py).
OUTLIER_FACTOR = 5.0  # times the median view's RMS error
OUTLIER_MIN_PX = 0.25
FloatArray = NDArray[np.float64]
_DISTORTION_COUNTS = (4, 5, 8, 12, 14)  # what cv2.calibrateCamera and solvePnP accept
# Names other OpenCV tools give the distortion (opencv_interactive-calibration writes dist_coeffs):
# refused, naming the key to use, rather than read as a second name of one field.
OTHER_DISTORTION_KEYS = ("dist_coeffs", "distCoeffs")


class BoardKind(StrEnum):
    """The calibration target."""

    CHESSBOARD = "chessboard"
    CHARUCO = "charuco"


@dataclass(frozen=True)
class Board:
    """A calibration board. Chessboard: `columns` × `rows` inner corners. ChArUco: squares.

    `square_m` is the side of one square; `marker_m` and `dictionary` are for ChArUco only.
    """

    kind: BoardKind
    columns: int
    rows: int
    square_m: float
    marker_m: float | None = None
    dictionary: str | None = None

    def describe(self) -> str:
        """One line, e.g. `chessboard 9x6 inner corners, 25 mm squares`."""
        if self.kind == BoardKind.CHESSBOARD:
            return f"chessboard {self.columns}x{self.rows} inner corners, {self.square_m * 1000:g} mm squares"
        assert self.marker_m is not None
        return (
            f"charuco {self.columns}x{self.rows} squares, {self.square_m * 1000:g} mm squares, "
            f"{self.marker_m * 1000:g} mm markers, {self.dictionary}"
        )


@dataclass(frozen=True)
class CameraCalibration:
    """A camera's intrinsics: pinhole matrix, distortion and the image size they hold for."""

    image_width: int
    image_height: int
    camera_matrix: NDArray[np.float64]  # (3, 3): fx 0 cx; 0 fy cy; 0 0 1 [px]
    distortion: NDArray[np.float64]  # (n,), OpenCV's order
    reprojection_error_px: float  # RMS over the calibration views' corners (0 if unknown)
    board: str = ""
    views: int = 0

    @property
    def fx_px(self) -> float:
        """Focal length along x [px]."""
        return float(self.camera_matrix[0, 0])

    @property
    def fy_px(self) -> float:
        """Focal length along y [px]."""
        return float(self.camera_matrix[1, 1])

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """(cx, cy) [px]."""
        return float(self.camera_matrix[0, 2]), float(self.camera_matrix[1, 2])

    def to_yaml(self) -> str:
        """The calibration as OpenCV FileStorage YAML text."""
        cv2 = require_cv2()
        fs = cv2.FileStorage("calibration.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
        fs.write("image_width", int(self.image_width))
        fs.write("image_height", int(self.image_height))
        fs.write("camera_matrix", np.asarray(self.camera_matrix, dtype=np.float64))
        fs.write("distortion_coefficients", np.asarray(self.distortion, dtype=np.float64).reshape(-1, 1))
        fs.write("avg_reprojection_error", float(self.reprojection_error_px))
        fs.write("board", self.board)
        fs.write("views", int(self.views))
        return str(fs.releaseAndGetString())


def write_calibration(
    calibration: CameraCalibration, path: str | os.PathLike[str], *, overwrite: bool
) -> None:
    """Write `path` atomically; an existing file is refused (InputError) unless `overwrite`."""
    p = Path(path)
    if p.exists() and not overwrite:
        raise InputError(f"--out {p}: exists; allowed: a new file (or --force to replace it)")
    if p.exists() and not p.is_file():
        raise InputError(f"--out {p}: not a regular file; allowed: a file path")
    text = calibration.to_yaml()
    try:
        atomic_write_text(p, text)
    except OSError as exc:
        raise InputError(f"--out {p}: cannot be written ({exc.strerror}); allowed: a writable path") from None


def _node(fs: Any, source: str, name: str) -> Any:
    node = fs.getNode(name)
    if node.empty():
        raise InputError(
            f"{source}: {name}: required field is missing; allowed: OpenCV FileStorage YAML (docs §9.1)"
        )
    return node


def parse_calibration(text: str, source: str) -> CameraCalibration:
    """Validate FileStorage YAML text; `InputError` naming `source` and the field on any problem."""
    cv2 = require_cv2()
    if not text.lstrip().startswith("%YAML"):
        raise InputError(
            f"{source}: not OpenCV FileStorage YAML (no %YAML header); allowed: docs/formats.md §9.1"
        )
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as exc:
        first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unreadable"
        raise InputError(f"{source}: not readable as OpenCV FileStorage YAML ({first})") from None
    try:
        lo, hi = IMAGE_SIDE_RANGE_PX
        sizes: list[int] = []
        for name in ("image_width", "image_height"):
            value = _node(fs, source, name).real()
            if not (math.isfinite(value) and value == int(value) and lo <= value <= hi):
                raise InputError(
                    f"{source}: {name}: {value:g} is out of range; allowed: an integer {lo} to {hi}"
                )
            sizes.append(int(value))
        matrix = _node(fs, source, "camera_matrix").mat()
        if matrix is None or np.shape(matrix) != (3, 3) or not np.all(np.isfinite(matrix)):
            raise InputError(f"{source}: camera_matrix: expected a finite 3x3 !!opencv-matrix")
        k = np.asarray(matrix, dtype=np.float64)
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        layout_ok = np.allclose(k[2], [0.0, 0.0, 1.0]) and k[1, 0] == 0.0
        if not (layout_ok and fx > 0 and fy > 0 and 0 <= cx <= sizes[0] and 0 <= cy <= sizes[1]):
            raise InputError(
                f"{source}: camera_matrix: not a pinhole matrix of this image; allowed: [[fx, s, cx], "
                f"[0, fy, cy], [0, 0, 1]] with fx, fy > 0, 0 <= cx <= image_width, 0 <= cy <= image_height"
            )
        for other in OTHER_DISTORTION_KEYS:
            if fs.getNode("distortion_coefficients").empty() and not fs.getNode(other).empty():
                raise InputError(
                    f"{source}: distortion_coefficients: required field is missing (the file has {other}, "
                    "another tool's name for it); allowed: the key distortion_coefficients (docs §9.1)"
                )
        dist_node = _node(fs, source, "distortion_coefficients").mat()
        dist = np.asarray(dist_node if dist_node is not None else [], dtype=np.float64).reshape(-1)
        if dist.size not in _DISTORTION_COUNTS or not np.all(np.isfinite(dist)) or np.any(np.abs(dist) > 1e4):
            raise InputError(
                f"{source}: distortion_coefficients: {dist.size} values; allowed: "
                f"{', '.join(map(str, _DISTORTION_COUNTS))} finite values (k1 k2 p1 p2 [k3 ...]), each "
                "within ±1e4"
            )
        error_node = fs.getNode("avg_reprojection_error")
        error = 0.0 if error_node.empty() else float(error_node.real())
        board_node = fs.getNode("board")
        board = "" if board_node.empty() else str(board_node.string())
        views_node = fs.getNode("views")
        views = 0 if views_node.empty() else int(views_node.real())
    finally:
        fs.release()
    return CameraCalibration(sizes[0], sizes[1], k, dist, error, board, views)


def load_calibration(path: str | os.PathLike[str]) -> CameraCalibration:
    """Read and validate a calibration file."""
    return parse_calibration(read_text_file(path, what="a camera calibration (OpenCV YAML)"), str(Path(path)))


def _charuco_board(cv2: Any, board: Board) -> Any:
    assert board.dictionary is not None and board.marker_m is not None
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
    return cv2.aruco.CharucoBoard((board.columns, board.rows), board.square_m, board.marker_m, dictionary)


def check_board(board: Board) -> None:
    """Refuse a board that cannot be found in an image (InputError naming the option)."""
    if board.columns < 2 or board.rows < 2 or max(board.columns, board.rows) > 100:
        raise InputError(f"--columns/--rows: {board.columns}x{board.rows}; allowed: 2 to 100 each")
    if not (1e-4 <= board.square_m <= 1.0):
        raise InputError(f"--square-m: {board.square_m:g}; allowed: 0.0001 to 1 m")
    if board.kind == BoardKind.CHARUCO:
        if board.marker_m is None or not (0 < board.marker_m < board.square_m):
            raise InputError("--marker-m: required for charuco; allowed: 0 < marker side < --square-m")
        if board.dictionary not in DICTIONARY_SIZES:
            raise InputError(
                f"--dictionary: {board.dictionary}; allowed: {', '.join(sorted(DICTIONARY_SIZES))}"
            )
        needed = (board.columns * board.rows) // 2
        if needed > DICTIONARY_SIZES[board.dictionary]:
            raise InputError(
                f"--dictionary: {board.dictionary} holds {DICTIONARY_SIZES[board.dictionary]} markers but a "
                f"{board.columns}x{board.rows} ChArUco board needs {needed}; allowed: a larger dictionary"
            )


def board_points(
    board: Board, image: NDArray[np.uint8]
) -> tuple[NDArray[np.float32], NDArray[np.float32]] | None:
    """(object points (N, 3) [m], image points (N, 2) [px]) of the board in a grey image; None if not seen."""
    cv2 = require_cv2()
    if board.kind == BoardKind.CHESSBOARD:
        found, corners = cv2.findChessboardCornersSB(image, (board.columns, board.rows), None)
        if not found:
            return None
        grid = np.mgrid[0 : board.columns, 0 : board.rows].T.reshape(-1, 2) * board.square_m
        obj = np.zeros((board.columns * board.rows, 3), np.float32)
        obj[:, :2] = grid
        return obj, np.asarray(corners, np.float32).reshape(-1, 2)
    charuco = _charuco_board(cv2, board)
    detector = cv2.aruco.CharucoDetector(charuco)
    corners, ids, _, _ = detector.detectBoard(image)
    if ids is None or np.asarray(ids).size < 6:  # fewer corners than a homography and the intrinsics need
        return None
    obj, img = charuco.matchImagePoints(corners, ids)
    return np.asarray(obj, np.float32).reshape(-1, 3), np.asarray(img, np.float32).reshape(-1, 2)


@dataclass(frozen=True)
class ViewFit:
    """How well one view's board corners fit the calibration that used them (or that it was dropped from)."""

    image: str
    rms_px: float  # RMS reprojection error over the view's corners
    max_px: float  # the largest corner's
    dropped: bool


@dataclass(frozen=True)
class CalibrationResult:
    """A calibration, each view's fit and the images skipped (board not found).

    When views were dropped as outliers, `with_dropped` is the calibration with every view, for
    comparison.
    """

    calibration: CameraCalibration
    used: tuple[str, ...]
    skipped: tuple[str, ...]
    views: tuple[ViewFit, ...] = ()  # every view with the board, in the order given
    outlier_threshold_px: float = 0.0
    with_dropped: CameraCalibration | None = None  # every view kept (None: none was dropped)

    @property
    def dropped(self) -> tuple[str, ...]:
        """The views dropped as outliers."""
        return tuple(v.image for v in self.views if v.dropped)


def _fit(
    cv2: Any,
    size: tuple[int, int],
    object_points: Sequence[NDArray[np.float32]],
    image_points: Sequence[NDArray[np.float32]],
) -> tuple[float, FloatArray, FloatArray, list[tuple[float, float]]]:
    """cv2.calibrateCamera: (RMS px, matrix, distortion, per view (RMS px, max px))."""
    rms, matrix, dist, rvecs, tvecs = cv2.calibrateCamera(
        list(object_points), list(image_points), size, None, None
    )
    errors = []
    for obj, img, rvec, tvec in zip(object_points, image_points, rvecs, tvecs, strict=True):
        projected, _ = cv2.projectPoints(obj, rvec, tvec, matrix, dist)
        distance = np.linalg.norm(projected.reshape(-1, 2) - img.reshape(-1, 2), axis=1)
        errors.append((float(np.sqrt(np.mean(distance**2))), float(distance.max())))
    return float(rms), np.asarray(matrix, np.float64), np.asarray(dist, np.float64).reshape(-1), errors


def outlier_threshold_px(view_rms_px: Sequence[float]) -> float:
    """The RMS reprojection error [px] above which a view is an outlier.

    `OUTLIER_FACTOR` times the median view's, and at least `OUTLIER_MIN_PX`.
    """
    return max(OUTLIER_MIN_PX, OUTLIER_FACTOR * float(np.median(view_rms_px)))


def calibrate_views(
    board: str,
    size: tuple[int, int],
    views: Sequence[tuple[str, NDArray[np.float32], NDArray[np.float32]]],
) -> tuple[CameraCalibration, tuple[ViewFit, ...], float, CameraCalibration | None]:
    """Calibrate from (image name, object points, image points) views, dropping outlier views.

    The worst view is dropped while its RMS reprojection error exceeds `outlier_threshold_px` of the
    views kept, and the camera calibrated again without it; at most a quarter of the views go, and
    at least `MIN_VIEWS` stay. Returns (the calibration, each view's fit in the order given, the
    threshold, the calibration with every view if any was dropped).
    """
    cv2 = require_cv2()
    kept = list(range(len(views)))
    first: CameraCalibration | None = None
    while True:
        rms, matrix, dist, errors = _fit(cv2, size, [views[i][1] for i in kept], [views[i][2] for i in kept])
        calibration = CameraCalibration(size[0], size[1], matrix, dist, rms, board, len(kept))
        if first is None:
            first = calibration
        threshold = outlier_threshold_px([e[0] for e in errors])
        worst = int(np.argmax([e[0] for e in errors]))
        room = len(kept) > max(MIN_VIEWS, len(views) - len(views) // 4)
        if errors[worst][0] <= threshold or not room:
            break
        del kept[worst]
    fits = dict(zip(kept, errors, strict=True))
    # a dropped view's fit: its corners against the final intrinsics, with its own best pose
    result = []
    for index, (name, obj, img) in enumerate(views):
        if index in fits:
            result.append(ViewFit(name, fits[index][0], fits[index][1], dropped=False))
            continue
        _, rvec, tvec = cv2.solvePnP(obj, img, calibration.camera_matrix, calibration.distortion)
        projected, _ = cv2.projectPoints(obj, rvec, tvec, calibration.camera_matrix, calibration.distortion)
        distance = np.linalg.norm(projected.reshape(-1, 2) - img.reshape(-1, 2), axis=1)
        result.append(
            ViewFit(name, float(np.sqrt(np.mean(distance**2))), float(distance.max()), dropped=True)
        )
    with_dropped = first if len(kept) < len(views) else None
    return calibration, tuple(result), threshold, with_dropped


def calibrate(board: Board, images: Sequence[tuple[str, NDArray[np.uint8]]]) -> CalibrationResult:
    """Calibrate from (name, grey image) views of `board`; InputError if too few views show it.

    Views whose reprojection error marks them as outliers are dropped and named (`calibrate_views`).
    """
    check_board(board)
    if not images:
        raise InputError("IMAGES: none given; allowed: at least 3 images of the board")
    size = images[0][1].shape[1], images[0][1].shape[0]
    views: list[tuple[str, NDArray[np.float32], NDArray[np.float32]]] = []
    skipped: list[str] = []
    for name, image in images:
        if (image.shape[1], image.shape[0]) != size:
            raise InputError(
                f"{name}: {image.shape[1]}x{image.shape[0]} px; allowed: every image the size of the first "
                f"({size[0]}x{size[1]})"
            )
        points = board_points(board, image)
        if points is None:
            skipped.append(name)
            continue
        views.append((name, points[0], points[1]))
    if len(views) < MIN_VIEWS:
        raise InputError(
            f"the board ({board.describe()}) was found in {len(views)} of {len(images)} images; allowed: at "
            f"least {MIN_VIEWS} (check --board, --columns and --rows)"
        )
    calibration, fits, threshold, with_dropped = calibrate_views(board.describe(), size, views)
    used = tuple(f.image for f in fits if not f.dropped)
    return CalibrationResult(calibration, used, tuple(skipped), fits, threshold, with_dropped)
