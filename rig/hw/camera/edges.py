"""A marker's corners from straight lines fitted to its four edges at sub-pixel precision, with covariance.

Along each side of the black square, from one cell after a corner to one cell before the next, the
image is sampled on short profiles across the edge (±`PROFILE_HALF_CELLS` of a cell, bilinear).
Each profile's edge point is where the area under the profile puts a sharp step between its dark
level (the darkest samples of its inner half) and its bright level (the brightest of its outer
half). A symmetric blur moves no straight edge's area, nor does an illumination gradient or the
pixel grid (the crossing of mid-grey would be pulled toward pixel centres on a sharp edge), so the
edges stay put on soft images, where a corner window (`cornerSubPix`) is drawn into the corner's
rounded tip. The points are undistorted (the camera's model), a straight line is fitted to each side
(total least squares, points beyond 3 robust sd dropped, fitted again on profiles re-centred on the
first line) and the corners are the intersections of neighbouring lines, distorted back into the
image.

Uncertainty: each line's offset and direction have the sd their residuals give (independent
points), plus what residuals cannot see: `EDGE_BIAS_FLOOR_PX` on the offset, `blur_tilt_floor_px`
on either end (a blur reaching the bit cells), and on the offset of a side whose white margin is
darker than the marker's brightest side (something dark within the blur's reach beyond it) that
shortfall times the profile's reach. The 8 corner coordinates' covariance is propagated from the 8
line parameters (two per line), so corners that share a line are correlated as they are.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

PROFILE_HALF_CELLS = 0.4  # profile reach either side of the edge: inside the border cell and the white margin
PROFILE_STEP_PX = 0.25
END_SAMPLES = 3  # samples at each end of a profile averaged for its dark and bright levels
MIN_STEP_GREY = 12.0  # a profile whose bright end is not this much above its dark end shows no edge
MIN_POINTS = 6  # fewer edge points on a side: no line (the marker's corners are kept as detected)
OUTLIER_SD = 3.0
MARGIN_LEVEL_ALLOWANCE = 0.03  # differences of a margin's level between sides taken as lighting, not shade
RISE_PER_SD = 2.563  # a Gaussian-blurred step rises from 10 % to 90 % over 2.563 sd
# The sd of a line's position that its residuals cannot show, fitted on rendered images (issue 32,
# benchmarks/bench_camera.py: errors within 2 sd in 92-99 % of joints at 44-71 px, blur σ 0-1.4 px)
EDGE_BIAS_FLOOR_PX = 0.03  # of its offset: sampling, rendering, a label not quite flat
BLUR_TILT_FLOOR = 5.0  # of its ends, times edge sd⁴ / cell³: see `blur_tilt_floor_px`


def blur_tilt_floor_px(edge_sd_px: float, cell_px: float) -> float:
    """The sd [px] by which either end of an edge line may sit off, beyond its residuals, on a blurred edge.

    A blur that reaches from the border's edge into the next cells mixes the bit cells (black or
    white, changing along the edge) into the profile's dark end, and so shifts the edge by different
    amounts along its length: the line turns. The shift grows steeply as the blur nears the profile's
    reach (`PROFILE_HALF_CELLS` of a cell), modelled as edge sd⁴ / cell³.
    """
    return BLUR_TILT_FLOOR * edge_sd_px**4 / cell_px**3


@dataclass(frozen=True)
class EdgeCorners:
    """Corners (4, 2) from the edge lines, their (8, 8) covariance [px²] (x0 y0 x1 y1 ...), edge width."""

    corners_px: FloatArray
    covariance_px2: FloatArray
    edge_residual_px: float  # RMS distance of the edge points from their lines
    edge_sd_px: float  # the edges' blur: the sd of a Gaussian that spreads a step as wide (median side)
    points: int  # edge points used, all four sides


@dataclass(frozen=True)
class _Line:
    """n·p = rho in undistorted pixels, with the sd of rho at the points' centroid and of the angle."""

    angle_rad: float  # direction of the normal n = (cos, sin)
    rho_px: float
    centroid_px: FloatArray
    rho_sd_px: float
    angle_sd_rad: float
    rms_px: float
    points: int


def _normal(angle_rad: float) -> FloatArray:
    return np.array([math.cos(angle_rad), math.sin(angle_rad)])


def _intersect(a: tuple[float, float], b: tuple[float, float]) -> FloatArray:
    """The point on both lines, each given as (normal angle, rho)."""
    matrix = np.array([_normal(a[0]), _normal(b[0])])
    return np.asarray(np.linalg.solve(matrix, np.array([a[1], b[1]])), np.float64)


class EdgeRefiner:
    """Fits a marker's edges in one grey image, for one camera model (matrix and distortion)."""

    def __init__(self, cv2: Any, camera_matrix: FloatArray, distortion: FloatArray, cells: int) -> None:
        self._cv2 = cv2
        self._matrix = np.asarray(camera_matrix, np.float64)
        self._dist = np.asarray(distortion, np.float64)
        self._cells = cells  # cells across a marker, its black border included

    def _undistort(self, points_px: FloatArray) -> FloatArray:
        undistorted = self._cv2.undistortPoints(
            points_px.reshape(-1, 1, 2), self._matrix, self._dist, P=self._matrix
        )
        return np.asarray(undistorted, np.float64).reshape(-1, 2)

    def _distort(self, points_px: FloatArray) -> FloatArray:
        rays = np.linalg.solve(self._matrix, np.vstack([points_px.T, np.ones(len(points_px))])).T
        projected, _ = self._cv2.projectPoints(rays, np.zeros(3), np.zeros(3), self._matrix, self._dist)
        return np.asarray(projected, np.float64).reshape(-1, 2)

    def _edge_points(
        self, image: NDArray[np.float32], start: FloatArray, end: FloatArray, outward: FloatArray, cell: float
    ) -> tuple[FloatArray, FloatArray, tuple[float, float]]:
        """Edge points (N, 2) in image pixels along start→end, with each one's 10-90 % rise [px].

        The profiles run along `outward`, from the dark border into the white margin. Also the median
        profile's (bright level, step) in grey levels.
        """
        count = max(MIN_POINTS, int(np.linalg.norm(end - start)))
        along = np.linspace(0.0, 1.0, count)
        bases = start[None, :] + along[:, None] * (end - start)[None, :]
        reach = PROFILE_HALF_CELLS * cell
        offsets = np.arange(-reach, reach + 1e-9, PROFILE_STEP_PX)
        xs = (bases[:, 0:1] + offsets[None, :] * outward[0]).astype(np.float32)
        ys = (bases[:, 1:2] + offsets[None, :] * outward[1]).astype(np.float32)
        values = np.asarray(
            self._cv2.remap(image, xs, ys, self._cv2.INTER_LINEAR, borderMode=self._cv2.BORDER_REPLICATE),
            np.float64,
        )
        # the levels: the darkest samples of the inner half, the brightest of the outer half (not the
        # ends: something dark lying on the white margin's outer half must not pull the bright level)
        half = len(offsets) // 2
        dark = np.sort(values[:, :half], axis=1)[:, :END_SAMPLES].mean(axis=1)
        bright = np.sort(values[:, -half:], axis=1)[:, -END_SAMPLES:].mean(axis=1)
        step = bright - dark
        usable = step >= MIN_STEP_GREY
        # Each profile's edge from its area, not from where it crosses mid-grey: interpolating a sharp
        # edge between pixel centres pulls the crossing toward them (up to 0.15 px on an edge along a
        # pixel row), while the area under the profile is kept. For a step at s, ∫(1 − bright share)
        # over the profile is s − offsets[0], whatever the blur.
        share = (values[usable] - dark[usable, None]) / step[usable, None]
        position = offsets[0] + np.trapezoid(1.0 - share, offsets, axis=1)
        rise = np.sum((share > 0.1) & (share < 0.9), axis=1) * PROFILE_STEP_PX
        inside = np.abs(position) <= reach  # else the profile missed the edge
        points = bases[usable][inside] + position[inside, None] * outward[None, :]
        levels = (
            (float(np.median(bright[usable])), float(np.median(step[usable]))) if np.any(usable) else (0, 1)
        )
        return np.asarray(points, np.float64), np.asarray(rise[inside], np.float64), levels

    def _fit(self, points_px: FloatArray, floor_px: float, tilt_floor_px: float) -> _Line | None:
        """Total least squares line through undistorted points, outliers beyond 3 robust sd dropped.

        `floor_px`: an sd of the line's position that its residuals do not show, added to the offset
        and, as if each end moved by it independently, to the direction.
        """
        points = self._undistort(points_px)
        keep = np.ones(len(points), bool)
        for _ in range(2):
            if keep.sum() < MIN_POINTS:
                return None
            chosen = points[keep]
            centroid = chosen.mean(axis=0)
            _, _, vt = np.linalg.svd(chosen - centroid)
            normal = vt[1]
            residuals = (points - centroid) @ normal
            spread = 1.4826 * float(np.median(np.abs(residuals[keep])))
            keep = np.abs(residuals) <= max(OUTLIER_SD * spread, 0.05)
        chosen = points[keep]
        if len(chosen) < MIN_POINTS:
            return None
        centroid = chosen.mean(axis=0)
        _, _, vt = np.linalg.svd(chosen - centroid)
        normal, direction = vt[1], vt[0]
        residuals = (chosen - centroid) @ normal
        along = (chosen - centroid) @ direction
        rms = math.sqrt(float(np.sum(residuals**2)) / max(len(chosen) - 2, 1))
        angle = math.atan2(normal[1], normal[0])
        spread = float(np.sum(along**2))
        return _Line(
            angle_rad=angle,
            rho_px=float(centroid @ normal),
            centroid_px=centroid,
            rho_sd_px=math.sqrt(rms**2 / len(chosen) + floor_px**2),
            angle_sd_rad=math.sqrt(rms**2 / spread + tilt_floor_px**2 / (spread / len(chosen))),
            rms_px=rms,
            points=len(chosen),
        )

    def refine(self, image: NDArray[np.float32], corners_px: FloatArray) -> EdgeCorners | None:
        """The corners (TL, TR, BR, BL) from the edge lines; None if a side shows too little edge."""
        quad = np.asarray(corners_px, np.float64)
        lines: list[_Line] = []
        edge_sds: list[float] = []
        brightness: list[tuple[float, float]] = []  # (bright level, step) per side
        reaches: list[float] = []
        centre = quad.mean(axis=0)
        for side in range(4):
            a, b = quad[side], quad[(side + 1) % 4]
            cell = float(np.linalg.norm(b - a)) / self._cells
            inset = (b - a) / self._cells  # one cell in from either corner
            direction = (b - a) / np.linalg.norm(b - a)
            outward = np.array([direction[1], -direction[0]])
            if outward @ ((a + b) / 2 - centre) < 0:
                outward = -outward
            points, _, _ = self._edge_points(image, a + inset, b - inset, outward, cell)
            line = self._fit(points, 0.0, 0.0) if len(points) >= MIN_POINTS else None
            if line is None:
                return None
            # second pass: profiles re-centred on the fitted line (the detected corners may be a pixel off)
            ends = self._distort(self._on_line(line, self._undistort(np.array([a + inset, b - inset]))))
            points, rises, levels = self._edge_points(image, ends[0], ends[1], outward, cell)
            if len(points) < MIN_POINTS:
                return None
            edge_sd = float(np.median(rises)) / RISE_PER_SD
            refit = self._fit(points, EDGE_BIAS_FLOOR_PX, blur_tilt_floor_px(edge_sd, cell))
            if refit is None:
                return None
            lines.append(refit)
            edge_sds.append(edge_sd)
            brightness.append(levels)
            reaches.append(PROFILE_HALF_CELLS * cell)
        # A side whose white margin looks darker than the others' (relative to its step) has something
        # dark within a blur's reach beyond it: the edge moves out with the level, the whole side at
        # once, which the corners' fit to a square cannot see (it turns the marker's tilt instead)
        brightest = max(bright for bright, _ in brightness)
        for k, line in enumerate(lines):
            bright, step = brightness[k]
            deficit = max(0.0, (brightest - bright) / step - MARGIN_LEVEL_ALLOWANCE)
            extra_px = deficit * reaches[k]
            lines[k] = dataclasses.replace(line, rho_sd_px=math.hypot(line.rho_sd_px, extra_px))
        params = np.array([[line.angle_rad, line.rho_px] for line in lines])

        def corners_from(p: FloatArray) -> FloatArray:
            # corner k (TL, TR, BR, BL) is where side k−1 (BL→TL) meets side k (TL→TR)
            undistorted = np.array(
                [_intersect((p[k - 1, 0], p[k - 1, 1]), (p[k, 0], p[k, 1])) for k in range(4)]
            )
            return self._distort(undistorted).reshape(-1)

        refined = corners_from(params)
        # line parameter covariance: rho at the centroid and the angle are independent; rho about the
        # origin then carries the angle's error through the centroid's position along the line
        jacobian = np.zeros((8, 8))
        covariance_params = np.zeros((8, 8))
        step = 1e-6
        for k, line in enumerate(lines):
            direction = np.array([-math.sin(line.angle_rad), math.cos(line.angle_rad)])
            lever = float(line.centroid_px @ direction)  # d rho / d angle at a fixed centroid
            block = np.array(
                [
                    [line.angle_sd_rad**2, lever * line.angle_sd_rad**2],
                    [lever * line.angle_sd_rad**2, line.rho_sd_px**2 + lever**2 * line.angle_sd_rad**2],
                ]
            )
            covariance_params[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = block
            for j in range(2):
                moved = params.copy()
                moved[k, j] += step
                jacobian[:, 2 * k + j] = (corners_from(moved) - refined) / step
        covariance = jacobian @ covariance_params @ jacobian.T
        points_used = sum(line.points for line in lines)
        residual = math.sqrt(sum(line.rms_px**2 * line.points for line in lines) / points_used)
        return EdgeCorners(
            corners_px=refined.reshape(4, 2),
            covariance_px2=covariance,
            edge_residual_px=residual,
            edge_sd_px=float(np.median(edge_sds)),
            points=points_used,
        )

    @staticmethod
    def _on_line(line: _Line, points: FloatArray) -> FloatArray:
        """Points moved perpendicularly onto the line."""
        normal = _normal(line.angle_rad)
        return np.asarray(points - ((points @ normal) - line.rho_px)[:, None] * normal[None, :], np.float64)
