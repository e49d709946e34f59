"""Synthetic camera images for tests and benchmarks: planar targets rendered through a camera model.

Each flat target (an ArUco marker with its white quiet zone, a chessboard, a ChArUco board) is drawn
exactly through the pinhole-and-distortion model: every output pixel is sampled at `supersample`²
points (one at a random place in each cell of an s × s grid over the pixel: a fixed grid would
place an edge that runs along a pixel row only to the nearest 1/s px), each point's ray
(`cv2.undistortPoints`) is intersected with the target's plane and the target's texture is read
there (bilinear), and the samples are averaged (anti-aliased edges, as a sensor integrates over a
pixel). Targets are drawn far to near, so a nearer one hides a farther
one. Then optional occluders (filled polygons in pixels), reduced contrast, an illumination
gradient across the image, Gaussian blur and Gaussian noise.

`render_link` places one marker per component of a link in a known configuration, in the
frames of docs/model.md §1 and the marker map's marker poses; `calibration_views` renders a board
from many poses. Needs OpenCV (the `camera` extra).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from model.chain import forward_kinematics
from rig.hw.camera.camera_calibration import Board, BoardKind
from rig.hw.camera.marker_map import MarkerMap
from rig.hw.camera.opencv import require_cv2

FloatArray = NDArray[np.float64]
QUIET_ZONE_FRACTION = 1.0 / 6.0  # white margin on each side of a marker, as a fraction of its side


@dataclass(frozen=True)
class SyntheticCamera:
    """A camera model to render with: pinhole matrix, OpenCV distortion, image size."""

    width: int = 1280
    height: int = 960
    fx_px: float = 1000.0
    fy_px: float = 1000.0
    cx_px: float = 643.5
    cy_px: float = 478.0
    distortion: tuple[float, ...] = (-0.08, 0.05, 0.0005, -0.0003, 0.0)

    @property
    def matrix(self) -> FloatArray:
        """The 3×3 camera matrix."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> FloatArray:
        """The distortion coefficients as an array."""
        return np.asarray(self.distortion, np.float64)


@dataclass(frozen=True)
class PlaneTarget:
    """A flat textured rectangle: texture (rows, cols) in [0, 1], its size, and its pose in the camera."""

    texture: NDArray[np.float32]
    width_m: float
    height_m: float
    cam_from_plane: FloatArray  # (4, 4); the plane's x right, y up as the texture is seen, z out of its face


@dataclass(frozen=True)
class Rendering:
    """Render settings: background grey, blur σ [px], noise σ [grey levels], occluders, seed.

    `contrast` scales every grey about mid-grey (1: black prints black; 0.6: the darkest ink 0.2);
    `illumination_gradient` dims the image linearly from its left edge (full light) to its right
    edge (1 − gradient), as a lamp to one side does.
    """

    background: float = 0.45
    blur_sigma_px: float = 0.0
    noise_sigma: float = 0.0
    contrast: float = 1.0
    illumination_gradient: float = 0.0
    supersample: int = 3
    occluders: tuple[tuple[NDArray[np.float64], float], ...] = field(
        default=()
    )  # (polygon (N, 2) px, grey 0-1)
    seed: int = 0


def _rays(
    camera: SyntheticCamera,
    supersample: int,
    box: tuple[int, int, int, int],
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """((y1−y0)·s, (x1−x0)·s, 2) normalised rays (x, y; z = 1) through the sample points of a pixel box.

    `box` is (x0, x1, y0, y1); each sample lies at a random place in its cell of an s × s grid over
    its pixel (stratified jitter).
    """
    cv2 = require_cv2()
    x0, x1, y0, y1 = box
    s = supersample
    offsets = np.arange(s) / s - 0.5
    xs = (np.arange(x0, x1)[:, None] + offsets[None, :]).reshape(-1)
    ys = (np.arange(y0, y1)[:, None] + offsets[None, :]).reshape(-1)
    grid_x, grid_y = np.meshgrid(xs, ys)
    grid_x = grid_x + rng.uniform(0.0, 1.0 / s, grid_x.shape)
    grid_y = grid_y + rng.uniform(0.0, 1.0 / s, grid_y.shape)
    pixels = np.stack([grid_x.reshape(-1), grid_y.reshape(-1)], axis=1)
    normalised = cv2.undistortPoints(pixels.reshape(-1, 1, 2), camera.matrix, camera.dist)
    return np.asarray(normalised.reshape(grid_x.shape[0], grid_x.shape[1], 2), np.float32)


def _draw(
    canvas: NDArray[np.float32],
    target: PlaneTarget,
    camera: SyntheticCamera,
    supersample: int,
    rng: np.random.Generator,
) -> None:
    cv2 = require_cv2()
    rotation = target.cam_from_plane[:3, :3]
    origin = target.cam_from_plane[:3, 3]
    normal = rotation[:, 2]
    if float(normal @ origin) >= 0:  # seen from behind (or edge-on)
        return
    hw, hh = target.width_m / 2, target.height_m / 2
    corners = np.array([[-hw, hh, 0], [hw, hh, 0], [hw, -hh, 0], [-hw, -hh, 0]], np.float64)
    # the outline, densely, so that distortion cannot bulge it past the bounding box
    outline = np.concatenate([np.linspace(corners[i], corners[(i + 1) % 4], 16) for i in range(4)])
    projected, _ = cv2.projectPoints(
        (rotation @ outline.T).T + origin, np.zeros(3), np.zeros(3), camera.matrix, camera.dist
    )
    projected = projected.reshape(-1, 2)
    x0 = max(int(np.floor(projected[:, 0].min())) - 2, 0)
    x1 = min(int(np.ceil(projected[:, 0].max())) + 3, camera.width)
    y0 = max(int(np.floor(projected[:, 1].min())) - 2, 0)
    y1 = min(int(np.ceil(projected[:, 1].max())) + 3, camera.height)
    if x0 >= x1 or y0 >= y1:
        return
    s = supersample
    rays = _rays(camera, s, (x0, x1, y0, y1), rng)
    ray_x, ray_y = rays[..., 0], rays[..., 1]  # z is 1
    # Elementwise rather than matrix products: (N, 3) @ (3, 3) goes through BLAS threads, which crawl
    # on a loaded machine.
    n = normal.astype(np.float32)
    depth = np.float32(normal @ origin) / (ray_x * n[0] + ray_y * n[1] + n[2])
    px = ray_x * depth - np.float32(origin[0])
    py = ray_y * depth - np.float32(origin[1])
    pz = depth - np.float32(origin[2])
    r = rotation.astype(np.float32)
    local_x = px * r[0, 0] + py * r[1, 0] + pz * r[2, 0]
    local_y = px * r[0, 1] + py * r[1, 1] + pz * r[2, 1]
    rows, cols = target.texture.shape
    map_x = (local_x + np.float32(hw)) * np.float32(cols / target.width_m) - np.float32(0.5)
    map_y = (np.float32(hh) - local_y) * np.float32(rows / target.height_m) - np.float32(0.5)
    sampled = cv2.remap(
        target.texture,
        map_x,
        map_y,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    inside = (depth > 0) & (np.abs(local_x) <= hw) & (np.abs(local_y) <= hh)
    under = np.repeat(np.repeat(canvas[y0:y1, x0:x1], s, axis=0), s, axis=1)
    mixed = np.where(inside, sampled, under).reshape(y1 - y0, s, x1 - x0, s)
    canvas[y0:y1, x0:x1] = mixed.mean(axis=(1, 3))


def render(
    targets: Sequence[PlaneTarget], camera: SyntheticCamera, rendering: Rendering
) -> NDArray[np.uint8]:
    """An 8-bit grey image of `targets` (drawn far to near), blurred, occluded and noisy as set."""
    cv2 = require_cv2()
    canvas = np.full((camera.height, camera.width), rendering.background, np.float32)
    rng = np.random.default_rng([rendering.seed, 1])  # the sample points' (the noise has its own)
    for target in sorted(targets, key=lambda t: -float(np.linalg.norm(t.cam_from_plane[:3, 3]))):
        _draw(canvas, target, camera, rendering.supersample, rng)
    for polygon, grey in rendering.occluders:
        cv2.fillPoly(canvas, [np.round(polygon).astype(np.int32)], float(grey), lineType=cv2.LINE_AA)
    if rendering.contrast != 1.0:
        canvas = np.float32(0.5) + (canvas - np.float32(0.5)) * np.float32(rendering.contrast)
    if rendering.illumination_gradient != 0.0:
        light = 1.0 - rendering.illumination_gradient * np.linspace(0.0, 1.0, camera.width, dtype=np.float32)
        canvas = canvas * light[None, :]
    image = canvas * 255.0
    if rendering.blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), rendering.blur_sigma_px)
    if rendering.noise_sigma > 0:
        image = image + np.random.default_rng(rendering.seed).normal(0.0, rendering.noise_sigma, image.shape)
    return np.asarray(np.clip(np.round(image), 0, 255), np.uint8)


def marker_texture(dictionary: str, marker_id: int, *, cell_px: int = 40) -> NDArray[np.float32]:
    """A marker (black border included) inside a white quiet zone of `QUIET_ZONE_FRACTION` per side."""
    cv2 = require_cv2()
    aruco_dict = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    cells = int(aruco_dict.markerSize) + 2
    side = cells * cell_px
    marker = cv2.aruco.generateImageMarker(aruco_dict, marker_id, side, borderBits=1)
    margin = round(side * QUIET_ZONE_FRACTION)
    texture = np.full((side + 2 * margin, side + 2 * margin), 255, np.uint8)
    texture[margin : margin + side, margin : margin + side] = marker
    return np.asarray(texture, np.float32) / 255.0


def look_down_pose(
    distance_m: float, centre_m: Sequence[float], tilt_rad: Sequence[float] = (0.0, 0.0)
) -> FloatArray:
    """cam_from_base for a camera `distance_m` above `centre_m` (base frame; y is up), looking down.

    The image's x axis runs along the base's z (the straight link's axis), its y along −x. `tilt_rad`
    turns the camera about its own x and y axes (a camera not quite square to the table).
    """
    base_from_cam = np.eye(4)
    axes = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # columns: camera x, y, z in base
    tx, ty = tilt_rad
    cx, sx, cy, sy = np.cos(tx), np.sin(tx), np.cos(ty), np.sin(ty)
    tilt = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    base_from_cam[:3, :3] = axes @ tilt
    base_from_cam[:3, 3] = np.asarray(centre_m, np.float64) - base_from_cam[:3, 2] * distance_m
    return np.asarray(np.linalg.inv(base_from_cam), np.float64)


def link_targets(
    marker_map: MarkerMap, transforms: FloatArray, cam_from_base: FloatArray
) -> list[PlaneTarget]:
    """One marker target per component of a link in configuration `transforms` ((J, 4, 4), §1)."""
    poses = forward_kinematics(transforms)  # (J+1, 4, 4): G_0 = I, G_i
    return [
        PlaneTarget(
            texture=marker_texture(marker_map.dictionary, component.marker_id),
            width_m=component.marker_length_m * (1 + 2 * QUIET_ZONE_FRACTION),
            height_m=component.marker_length_m * (1 + 2 * QUIET_ZONE_FRACTION),
            cam_from_plane=cam_from_base @ poses[component.component] @ component.pose_in_component,
        )
        for component in marker_map.components
    ]


def render_link(
    marker_map: MarkerMap,
    transforms: FloatArray,
    cam_from_base: FloatArray,
    camera: SyntheticCamera,
    rendering: Rendering,
) -> NDArray[np.uint8]:
    """An image of the link's markers in configuration `transforms`, seen from `cam_from_base`."""
    return render(link_targets(marker_map, transforms, cam_from_base), camera, rendering)


def marker_outline_px(
    marker_map: MarkerMap,
    transforms: FloatArray,
    cam_from_base: FloatArray,
    camera: SyntheticCamera,
    component: int,
) -> FloatArray:
    """(4, 2) image corners of one component's marker (black square), for placing occluders."""
    cv2 = require_cv2()
    target = link_targets(marker_map, transforms, cam_from_base)[component]
    h = marker_map.components[component].marker_length_m / 2
    square = np.array([[-h, h, 0, 1], [h, h, 0, 1], [h, -h, 0, 1], [-h, -h, 0, 1]], np.float64)
    points = (target.cam_from_plane @ square.T).T[:, :3]
    projected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.matrix, camera.dist)
    return np.asarray(projected, np.float64).reshape(4, 2)


def board_target(board: Board, cam_from_board: FloatArray, *, square_px: int = 60) -> PlaneTarget:
    """A chessboard (inner corners columns × rows) or ChArUco board with a one-square white margin."""
    cv2 = require_cv2()
    if board.kind == BoardKind.CHESSBOARD:
        squares_x, squares_y = board.columns + 1, board.rows + 1
        cells = np.indices((squares_y, squares_x)).sum(axis=0) % 2
        pattern = np.kron(cells, np.ones((square_px, square_px)))
        texture = np.pad(pattern, square_px, constant_values=1.0).astype(np.float32)
        # the first inner corner is the board's object point (0, 0): shift the plane so it sits there
        width = (squares_x + 2) * board.square_m
        height = (squares_y + 2) * board.square_m
        offset = np.array([-2 * board.square_m + width / 2, 2 * board.square_m - height / 2, 0.0])
    else:
        assert board.dictionary is not None and board.marker_m is not None
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
        charuco = cv2.aruco.CharucoBoard(
            (board.columns, board.rows), board.square_m, board.marker_m, dictionary
        )
        size = ((board.columns + 2) * square_px, (board.rows + 2) * square_px)
        texture = np.asarray(charuco.generateImage(size, marginSize=square_px), np.float32) / 255.0
        width = (board.columns + 2) * board.square_m
        height = (board.rows + 2) * board.square_m
        offset = np.array([-board.square_m + width / 2, board.square_m - height / 2, 0.0])
    # Board object points run x right and y *down* the printed board (OpenCV), the plane's y up: flip y, z.
    board_from_plane = np.diag([1.0, -1.0, -1.0, 1.0])
    board_from_plane[:3, 3] = offset * np.array([1.0, -1.0, 1.0])
    return PlaneTarget(texture, width, height, cam_from_board @ board_from_plane)


def _board_extent_m(board: Board) -> NDArray[np.float64]:
    """The span (x, y) [m] of the board's object points."""
    if board.kind == BoardKind.CHESSBOARD:
        return np.array([board.columns - 1, board.rows - 1]) * board.square_m
    return np.array([board.columns, board.rows]) * board.square_m


def _board_view(
    board: Board, camera: SyntheticCamera, rvec: FloatArray, depth_m: float, centre_px: tuple[float, float]
) -> tuple[FloatArray, bool]:
    """cam_from_board for the board turned by `rvec`, its centre seen at `centre_px` `depth_m` away.

    And whether the whole board lies 20 px or more inside the image.
    """
    cv2 = require_cv2()
    rotation, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    extent = _board_extent_m(board)
    u, v = centre_px
    centre = np.array([(u - camera.cx_px) / camera.fx_px, (v - camera.cy_px) / camera.fy_px, 1.0]) * depth_m
    cam_from_board = np.eye(4)
    cam_from_board[:3, :3] = rotation
    cam_from_board[:3, 3] = centre - rotation @ np.array([extent[0] / 2, extent[1] / 2, 0.0])
    corners = np.array(
        [[0, 0, 0], [extent[0], 0, 0], [extent[0], extent[1], 0], [0, extent[1], 0]], np.float64
    )
    projected, _ = cv2.projectPoints(corners, rvec, cam_from_board[:3, 3], camera.matrix, camera.dist)
    p = projected.reshape(-1, 2)
    margin = 20
    inside = bool(
        p[:, 0].min() >= margin
        and p[:, 1].min() >= margin
        and p[:, 0].max() <= camera.width - margin
        and p[:, 1].max() <= camera.height - margin
    )
    return cam_from_board, inside


CALIBRATION_RENDERING = Rendering(background=0.5, blur_sigma_px=0.6, noise_sigma=2.0)


def calibration_views(
    board: Board,
    camera: SyntheticCamera,
    count: int,
    *,
    seed: int = 0,
    distance_m: tuple[float, float] = (0.25, 0.5),
) -> list[NDArray[np.uint8]]:
    """`count` images of `board` from random poses over the whole image, tilted up to about 35°, in view."""
    rng = np.random.default_rng(seed)
    images: list[NDArray[np.uint8]] = []
    while len(images) < count:
        rvec = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-0.3, 0.3)])
        depth = rng.uniform(*distance_m)
        # aim the board's centre at a random point of the image's inner part
        u = rng.uniform(0.15, 0.85) * camera.width
        v = rng.uniform(0.15, 0.85) * camera.height
        cam_from_board, inside = _board_view(board, camera, rvec, depth, (u, v))
        if not inside:
            continue
        rendering = dataclasses.replace(CALIBRATION_RENDERING, seed=len(images))
        images.append(render([board_target(board, cam_from_board)], camera, rendering))
    return images


def tilted_view(
    board: Board, camera: SyntheticCamera, tilt_rad: float, *, distance_m: float, blur_sigma_px: float
) -> NDArray[np.uint8]:
    """One image of `board` in the middle of the image, turned `tilt_rad` about its x axis."""
    cam_from_board, inside = _board_view(
        board, camera, np.array([tilt_rad, 0.0, 0.0]), distance_m, (camera.cx_px, camera.cy_px)
    )
    if not inside:
        raise ValueError(f"the board tilted {tilt_rad:g} rad at {distance_m:g} m does not fit the image")
    rendering = dataclasses.replace(CALIBRATION_RENDERING, blur_sigma_px=blur_sigma_px, seed=1000)
    return render([board_target(board, cam_from_board)], camera, rendering)
