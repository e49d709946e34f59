"""A link configuration from one camera image: ArUco markers → component poses → joint rotations.

For each component's marker (`MarkerMap`): its four corners (found by ArUco, refined by the map's
`corner_refinement`: by default from lines fitted to the marker's edges, `rig.hw.camera.edges`), its
pose by
`cv2.solvePnPGeneric` with `SOLVEPNP_IPPE_SQUARE` (both planar solutions), then the component's pose
from the marker's pose in its frame. A small or face-on marker has two solutions that reproject
almost equally well and differ mostly in tilt; the choice is made along the chain (a Viterbi pass
over the two candidates of each marker) so that consecutive components turn about their bending
axis rather than tilt, with a penalty per pixel of extra reprojection error. Joint rotations and
planar angles follow by `model.joint_rotation` (docs/formats.md §9.3 for the conventions).

Uncertainty: with `edges` refinement each marker's corners come with their (8, 8) covariance C from
the edge lines (`rig.hw.camera.edges`), widened by the χ² of the corners' own fit to a square where
that exceeds its 95 % point (something the lines did not see bent them). With ArUco's refinements
the corner noise σ [px] is estimated from the reprojection residuals of all markers in the image (2
degrees of freedom each: 8 corner coordinates, 6 pose parameters), floored at `MIN_CORNER_SIGMA_PX`,
and raised for a marker whose own residuals are larger: C = σ²I. Each marker's rotation covariance
is (JᵀC⁻¹J)⁻¹ from the projection's Jacobian, and is carried to each planar angle and to the
out-of-plane test by numerical gradients. The result is a first-order standard deviation: it does
not cover a wrong marker map, a wrong calibration or a flipped solution.

A component whose marker is not found is `MarkerNotSeenError`, naming it: never a guessed angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from model.joint_rotation import (
    joint_rotations,
    joint_transforms,
    out_of_plane_vector,
    planar_projection,
    rotation_angle_rad,
)
from rig.errors import InputError, RigError
from rig.hw.camera.camera_calibration import CameraCalibration
from rig.hw.camera.edges import EdgeCorners, EdgeRefiner
from rig.hw.camera.marker_map import ComponentMarker, CornerRefinement, MarkerMap
from rig.hw.camera.opencv import require_cv2
from rig.hw.seams import ConfigurationReading

MIN_CORNER_SIGMA_PX = 0.1  # floor: the residuals of 4 corners under-report the noise of refined corners
FALLBACK_WINDOW_CELLS = 0.3  # cornerSubPix's half-window, of a cell, where a marker's edges cannot be fitted
MISFIT_CHI2 = 5.99  # χ²(2) exceeded with probability 0.05: a marker's corners fit its square worse
AMBIGUITY_MARGIN_PX = 1.0  # a second IPPE solution within this of the best is a candidate
OUT_OF_PLANE_CHI2 = 23.03  # χ²(2) exceeded with probability 1e-5 (the tilt noise has heavier tails)
REPROJECTION_PENALTY_RAD_PER_PX = 0.05  # chain choice: 1 px of extra error weighs like 2.9° of tilt

FloatArray = NDArray[np.float64]


class MarkerNotSeenError(RigError):
    """A component's marker was not found in the image: the configuration cannot be measured."""


@dataclass(frozen=True)
class MarkerPose:
    """One component's marker as seen: the pose chosen and what it rests on."""

    component: int
    marker_id: int
    corners_px: FloatArray  # (4, 2) TL, TR, BR, BL as printed
    rotation: FloatArray  # (3, 3) marker axes in the camera frame
    translation_m: FloatArray  # (3,) marker centre in the camera frame
    reprojection_error_px: float  # RMS over the 4 corners, chosen solution
    side_px: float  # mean side of the marker in the image
    candidates: int  # planar solutions within AMBIGUITY_MARGIN_PX (1 or 2)
    rvec: FloatArray  # (3,) Rodrigues vector of `rotation`
    rotation_covariance: FloatArray  # (3, 3) of `rvec` [rad²]


@dataclass(frozen=True)
class CameraMeasurement:
    """A configuration measured from one image; arrays are base to tip (joint i at index i − 1)."""

    source: str  # the image file, or the camera device
    time_ns: int
    markers: tuple[MarkerPose, ...]  # one per component, base first
    joint_rotations: FloatArray  # (J, 3, 3) R_i, the rotation of {i} in {i−1}
    transforms: FloatArray  # (J, 4, 4) [R_i, (0, 0, L_i)]
    planar_angles_rad: FloatArray  # (J,) φ_i, the projection about y
    planar_angle_sd_rad: FloatArray  # (J,) first-order standard deviation of φ_i
    out_of_plane_rad: FloatArray  # (J,) angle of Rot_y(φ_i)ᵀ R_i
    out_of_plane_statistic: FloatArray  # (J,) vᵀΣ⁻¹v of its tilt-and-twist vector: χ² with 2 dof if planar
    joint_gap_m: FloatArray  # (J,) distance between joint i's centre as placed by components i−1 and i
    corner_sigma_px: float  # the corner noise the uncertainty assumes (RMS over the markers' corners)
    planar_tolerance_rad: float

    @property
    def planar(self) -> bool:
        """No joint is out of plane both beyond the map's tolerance and beyond its measurement noise.

        A joint counts as out of plane when its out-of-plane angle exceeds `planar_tolerance_rad` and
        its test statistic exceeds `OUT_OF_PLANE_CHI2` (rarely, for a planar joint).
        """
        beyond = (self.out_of_plane_rad > self.planar_tolerance_rad) & (
            self.out_of_plane_statistic > OUT_OF_PLANE_CHI2
        )
        return not bool(np.any(beyond))

    def reading(self) -> ConfigurationReading:
        """The seam's record: transforms always, planar angles only when the link lies in a plane."""
        angles = tuple(float(a) for a in self.planar_angles_rad) if self.planar else None
        return ConfigurationReading(
            transforms=self.transforms.copy(), time_ns=self.time_ns, joint_angles_rad=angles
        )

    def as_dict(self) -> dict[str, Any]:
        """Plain values for JSON (`rig config measure --json`, docs/formats.md §9.4)."""
        return {
            "source": self.source,
            "time_ns": self.time_ns,
            "planar": self.planar,
            "planar_tolerance_rad": self.planar_tolerance_rad,
            "corner_sigma_px": self.corner_sigma_px,
            "joint_angles_rad": [float(a) for a in self.planar_angles_rad],
            "joint_angles_deg": [math.degrees(a) for a in self.planar_angles_rad],
            "joint_angle_sd_rad": [float(s) for s in self.planar_angle_sd_rad],
            "out_of_plane_rad": [float(a) for a in self.out_of_plane_rad],
            "out_of_plane_statistic": [float(a) for a in self.out_of_plane_statistic],
            "joint_gap_m": [float(g) for g in self.joint_gap_m],
            "transforms": self.transforms.tolist(),
            "markers": [
                {
                    "component": m.component,
                    "marker_id": m.marker_id,
                    "side_px": m.side_px,
                    "reprojection_error_px": m.reprojection_error_px,
                    "candidates": m.candidates,
                }
                for m in self.markers
            ],
        }


def _object_points(length_m: float) -> NDArray[np.float32]:
    """The marker's corners in its own frame, in ArUco's corner order (for IPPE_SQUARE)."""
    h = length_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]], dtype=np.float32)


class MarkerDetector:
    """ArUco detection and pose candidates for one marker map and one calibrated camera."""

    def __init__(self, marker_map: MarkerMap, calibration: CameraCalibration) -> None:
        cv2 = require_cv2()
        self._cv2 = cv2
        self.marker_map = marker_map
        self.calibration = calibration
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, marker_map.dictionary))
        parameters = cv2.aruco.DetectorParameters()
        refinement = marker_map.corner_refinement
        # edges: ArUco's corners unrefined, then the edge lines (rig.hw.camera.edges)
        aruco_method = "none" if refinement == CornerRefinement.EDGES else refinement.value
        parameters.cornerRefinementMethod = getattr(cv2.aruco, f"CORNER_REFINE_{aruco_method.upper()}")
        if refinement == CornerRefinement.SUBPIX:
            # half-size 2 (a 5x5 window): a larger one reaches past the white margin, and anything lying
            # beside the label bends the corners (benchmarks/bench_camera.py: 0.41° to 0.15° RMS at 50 px)
            parameters.cornerRefinementWinSize = 2
        self.detector = cv2.aruco.ArucoDetector(dictionary, parameters)
        self._objects = {c.marker_id: _object_points(c.marker_length_m) for c in marker_map.components}
        self._matrix = np.asarray(calibration.camera_matrix, np.float64)
        self._dist = np.asarray(calibration.distortion, np.float64)
        self._cells = int(dictionary.markerSize) + 2  # across a marker, its black border included
        self._edges = (
            EdgeRefiner(cv2, self._matrix, self._dist, self._cells)
            if refinement == CornerRefinement.EDGES
            else None
        )

    def detect(self, image: NDArray[np.uint8]) -> dict[int, FloatArray]:
        """Corners (4, 2) by marker id, for the ids seen exactly once."""
        corners, ids, _ = self.detector.detectMarkers(image)
        found: dict[int, FloatArray] = {}
        twice: set[int] = set()
        if ids is None:
            return found
        for marker_id, quad in zip(np.asarray(ids).reshape(-1), corners, strict=True):
            key = int(marker_id)
            if key in found:
                twice.add(key)
            found[key] = np.asarray(quad, np.float64).reshape(4, 2)
        for key in twice:  # seen twice: no telling which is the component's
            del found[key]
        return found

    def refine(self, image: NDArray[np.uint8], corners: FloatArray) -> tuple[FloatArray, EdgeCorners | None]:
        """The corners refined as the map says, and their edge lines' fit (`edges` refinement only).

        With `edges`, a marker a side of which shows too little edge to fit (mostly hidden) gets
        `cv2.cornerSubPix` instead, with a window of `FALLBACK_WINDOW_CELLS` of its cell, and no fit.
        """
        if self._edges is None:
            return corners, None
        fit = self._edges.refine(np.asarray(image, np.float32), corners)
        if fit is not None:
            return fit.corners_px, fit
        cell_px = float(np.mean(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1))) / self._cells
        half = max(2, round(FALLBACK_WINDOW_CELLS * cell_px))
        criteria = (self._cv2.TERM_CRITERIA_EPS + self._cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        refined = self._cv2.cornerSubPix(
            image, corners.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), criteria
        )
        return np.asarray(refined, np.float64).reshape(4, 2), None

    def candidates(self, marker_id: int, corners: FloatArray) -> list[tuple[FloatArray, FloatArray, float]]:
        """The planar pose solutions (rvec, tvec, RMS reprojection error px) worth considering, best first."""
        cv2 = self._cv2
        count, rvecs, tvecs, errors = cv2.solvePnPGeneric(
            self._objects[marker_id],
            corners.astype(np.float32),
            self._matrix,
            self._dist,
            flags=cv2.SOLVEPNP_IPPE_SQUARE,
        )
        errs = np.asarray(errors, np.float64).reshape(-1)
        solutions = sorted(
            (
                (
                    np.asarray(rvecs[i], np.float64).reshape(3),
                    np.asarray(tvecs[i], np.float64).reshape(3),
                    float(errs[i]),
                )
                for i in range(int(count))
            ),
            key=lambda s: s[2],
        )
        best = solutions[0][2]
        return [s for s in solutions if s[2] - best <= AMBIGUITY_MARGIN_PX and s[1][2] > 0]

    def project(self, marker_id: int, rvec: FloatArray, tvec: FloatArray) -> FloatArray:
        """The marker's corners (4, 2) [px] seen in pose (rvec, tvec)."""
        projected, _ = self._cv2.projectPoints(self._objects[marker_id], rvec, tvec, self._matrix, self._dist)
        return np.asarray(projected, np.float64).reshape(4, 2)

    def rotation_covariance(
        self, marker_id: int, rvec: FloatArray, tvec: FloatArray, corner_covariance_px2: FloatArray
    ) -> FloatArray:
        """(JᵀC⁻¹J)⁻¹ restricted to the rotation vector.

        J is the corners' Jacobian in (rvec, tvec), C the (8, 8) covariance of the corners'
        coordinates (x0, y0, x1, ...).
        """
        _, jacobian = self._cv2.projectPoints(self._objects[marker_id], rvec, tvec, self._matrix, self._dist)
        jac = np.asarray(jacobian, np.float64)[:, :6]
        information = jac.T @ np.linalg.pinv(corner_covariance_px2) @ jac
        covariance = np.linalg.pinv(information)
        return np.asarray(covariance[:3, :3], np.float64)


def _rodrigues(cv2: Any, rvec: FloatArray) -> FloatArray:
    rotation, _ = cv2.Rodrigues(rvec)
    return np.asarray(rotation, np.float64)


def _component_rotation(cv2: Any, rvec: FloatArray, component: ComponentMarker) -> FloatArray:
    return _rodrigues(cv2, rvec) @ component.pose_in_component[:3, :3].T


def _choose_along_chain(
    cv2: Any,
    components: tuple[ComponentMarker, ...],
    options: list[list[tuple[FloatArray, FloatArray, float]]],
) -> list[int]:
    """Index of the chosen candidate per component: least total out-of-plane turning plus error penalty."""
    rotations = [
        [_component_rotation(cv2, c[0], comp) for c in opts]
        for comp, opts in zip(components, options, strict=True)
    ]
    unary = [[REPROJECTION_PENALTY_RAD_PER_PX * (c[2] - opts[0][2]) for c in opts] for opts in options]
    cost = list(unary[0])
    back: list[list[int]] = []
    for k in range(1, len(options)):
        step_cost: list[float] = []
        step_back: list[int] = []
        for b, rot_b in enumerate(rotations[k]):
            totals = []
            for a, rot_a in enumerate(rotations[k - 1]):
                _, tilt = planar_projection((rot_a.T @ rot_b)[None])
                totals.append(cost[a] + float(tilt[0]))
            best = int(np.argmin(totals))
            step_cost.append(totals[best] + unary[k][b])
            step_back.append(best)
        cost = step_cost
        back.append(step_back)
    choice = [int(np.argmin(cost))]
    for step in reversed(back):
        choice.append(step[choice[-1]])
    return choice[::-1]


def measure_image(
    detector: MarkerDetector,
    image: NDArray[np.uint8],
    *,
    source: str,
    time_ns: int,
    along_chain: bool = True,
) -> CameraMeasurement:
    """Measure the link in one grey image; `MarkerNotSeenError` naming every component not seen.

    `along_chain=False` keeps each marker's best-reprojecting pose instead of choosing along the
    chain (for comparison: benchmarks/bench_camera.py --choice best).
    """
    cv2 = require_cv2()
    marker_map = detector.marker_map
    calibration = detector.calibration
    height, width = image.shape[:2]
    if (width, height) != (calibration.image_width, calibration.image_height):
        raise InputError(
            f"{source}: {width}x{height} px; allowed: the calibration's image size "
            f"{calibration.image_width}x{calibration.image_height}"
        )
    seen = detector.detect(image)
    missing = [c for c in marker_map.components if c.marker_id not in seen]
    if missing:
        names = ", ".join(f"{c.name} (component {c.component}, marker {c.marker_id})" for c in missing)
        seen_ids = sorted(seen)
        raise MarkerNotSeenError(
            f"{source}: marker not seen for {names}; markers seen: {seen_ids if seen_ids else 'none'}; "
            f"nothing measured ({marker_map.dictionary}, map {marker_map.source})"
        )
    corners = [seen[c.marker_id] for c in marker_map.components]
    refined = [detector.refine(image, quad) for quad in corners]
    corners = [quad for quad, _ in refined]
    edges = [edge for _, edge in refined]
    options = []
    for component, quad in zip(marker_map.components, corners, strict=True):
        found = detector.candidates(component.marker_id, quad)
        if not found:
            raise MarkerNotSeenError(
                f"{source}: {component.name} (marker {component.marker_id}): no pose in front of the camera"
            )
        options.append(found)
    choice = _choose_along_chain(cv2, marker_map.components, options) if along_chain else [0] * len(options)
    chosen = [opts[i] for opts, i in zip(options, choice, strict=True)]

    squared = sum(4 * c[2] ** 2 for c in chosen)  # sum of squared corner distances (4 corners each)
    dof = 2 * len(chosen)  # per marker: 8 coordinates − 6 pose parameters
    sigma = max(MIN_CORNER_SIGMA_PX, math.sqrt(squared / dof))

    markers = []
    corner_covariances: list[FloatArray] = []
    for component, quad, (rvec, tvec, error), options_k, edge in zip(
        marker_map.components, corners, chosen, options, edges, strict=True
    ):
        sides = np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)
        if edge is not None:
            # the corners' own fit to a square: beyond what their covariance allows (χ² with 2 degrees
            # of freedom above its 95 % point), something the lines did not see bends them: widen
            residual = (quad - detector.project(component.marker_id, rvec, tvec)).reshape(-1)
            misfit = float(residual @ np.linalg.pinv(edge.covariance_px2) @ residual)
            corner_covariance = edge.covariance_px2 * max(1.0, misfit / MISFIT_CHI2)
        else:
            # a marker that fits its own corners worse than the image's pooled noise gets its own
            # (one marker's 4 corners leave 2 degrees of freedom: σ_k² = 4 e_k² / 2)
            corner_covariance = np.eye(8) * max(sigma, math.sqrt(2.0) * error) ** 2
        corner_covariances.append(corner_covariance)
        markers.append(
            MarkerPose(
                component=component.component,
                marker_id=component.marker_id,
                corners_px=quad,
                rotation=_rodrigues(cv2, rvec),
                translation_m=tvec,
                reprojection_error_px=error,
                side_px=float(sides.mean()),
                candidates=len(options_k),
                rvec=rvec,
                rotation_covariance=detector.rotation_covariance(
                    component.marker_id, rvec, tvec, corner_covariance
                ),
            )
        )
    component_rotations = np.stack(
        [_component_rotation(cv2, m.rvec, c) for m, c in zip(markers, marker_map.components, strict=True)]
    )
    rotations = joint_rotations(component_rotations)
    angles, tilt = planar_projection(rotations)
    sd, tilt_statistic = _joint_uncertainty(cv2, markers, marker_map.components)
    transforms = joint_transforms(rotations, marker_map.segment_lengths_m)
    gaps = _joint_gaps(markers, marker_map.components, transforms)
    return CameraMeasurement(
        source=source,
        time_ns=time_ns,
        markers=tuple(markers),
        joint_rotations=rotations,
        transforms=transforms,
        planar_angles_rad=angles,
        planar_angle_sd_rad=sd,
        out_of_plane_rad=tilt,
        out_of_plane_statistic=tilt_statistic,
        joint_gap_m=gaps,
        corner_sigma_px=float(np.sqrt(np.mean([np.mean(np.diag(c)) for c in corner_covariances]))),
        planar_tolerance_rad=marker_map.planar_tolerance_rad,
    )


def _joint_uncertainty(
    cv2: Any, markers: list[MarkerPose], components: tuple[ComponentMarker, ...]
) -> tuple[FloatArray, FloatArray]:
    """Per joint: the sd of φ_i, and the out-of-plane test statistic vᵀΣ⁻¹v (v = `out_of_plane_vector`).

    Both by first-order propagation of markers i−1 and i's rotation covariances through numerical
    gradients.
    """
    step = 1e-6
    joints = len(markers) - 1
    sd = np.zeros(joints)
    statistic = np.zeros(joints)

    def values(rvec_before: FloatArray, rvec_after: FloatArray, i: int) -> FloatArray:
        before = _component_rotation(cv2, rvec_before, components[i - 1])
        after = _component_rotation(cv2, rvec_after, components[i])
        relative = before.T @ after
        return np.array([math.atan2(relative[0, 2], relative[2, 2]), *out_of_plane_vector(relative)])

    for i in range(1, len(markers)):
        centre = values(markers[i - 1].rvec, markers[i].rvec, i)
        covariance = np.zeros((3, 3))
        for k in (i - 1, i):
            jacobian = np.zeros((3, 3))
            for axis in range(3):
                rvec = markers[k].rvec.copy()
                rvec[axis] += step
                moved = (
                    values(rvec, markers[i].rvec, i) if k == i - 1 else values(markers[i - 1].rvec, rvec, i)
                )
                change = moved - centre
                change[0] = math.remainder(change[0], math.tau)
                jacobian[:, axis] = change / step
            covariance += jacobian @ markers[k].rotation_covariance @ jacobian.T
        sd[i - 1] = math.sqrt(max(covariance[0, 0], 0.0))
        tilt = centre[1:]
        statistic[i - 1] = float(tilt @ np.linalg.pinv(covariance[1:, 1:]) @ tilt)
    return sd, statistic


def _joint_gaps(
    markers: list[MarkerPose], components: tuple[ComponentMarker, ...], transforms: FloatArray
) -> FloatArray:
    """|o_i placed by component i−1 (through p_i) − o_i placed by component i| [m], per joint."""
    poses = []
    for marker, component in zip(markers, components, strict=True):
        cam_from_marker = np.eye(4)
        cam_from_marker[:3, :3] = marker.rotation
        cam_from_marker[:3, 3] = marker.translation_m
        poses.append(cam_from_marker @ np.linalg.inv(component.pose_in_component))
    gaps = [
        float(np.linalg.norm((poses[i - 1] @ np.append(transforms[i - 1][:3, 3], 1.0))[:3] - poses[i][:3, 3]))
        for i in range(1, len(poses))
    ]
    return np.asarray(gaps, np.float64)


def rotation_error_rad(measured: FloatArray, truth: FloatArray) -> float:
    """The angle of the rotation between two rotations (for tests and benchmarks)."""
    return rotation_angle_rad(np.asarray(measured).T @ np.asarray(truth))
