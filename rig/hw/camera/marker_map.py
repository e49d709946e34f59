"""The marker map (docs/formats.md §9.2): which ArUco marker sits where on which component of the link.

A YAML file, validated here without OpenCV: the dictionary, the markers' side length (one for the
map, which a component may override), one marker per component (base first) with its pose in the
component's frame, and the link's segment lengths
(the joint centres' positions, `p_i = (0, 0, L_i)` in {i−1}, docs/model.md §1). Every problem is a
one-line `ConfigError` naming the file, the field path and what is allowed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from model.chain import pose_from_xyz_rpy
from rig.inputs.files import load_yaml_file
from rig.inputs.validate import Section

# OpenCV's predefined ArUco dictionaries and how many markers each holds (cv2.aruco.DICT_*;
# tests/test_camera.py checks the counts against the installed OpenCV).
DICTIONARY_SIZES: dict[str, int] = {
    **{f"DICT_{bits}X{bits}_{n}": n for bits in (4, 5, 6, 7) for n in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": 1024,
    "DICT_ARUCO_MIP_36H12": 250,
    "DICT_APRILTAG_16H5": 30,
    "DICT_APRILTAG_25H9": 35,
    "DICT_APRILTAG_36H10": 2320,
    "DICT_APRILTAG_36H11": 587,
}

MARKER_LENGTH_RANGE_M = (0.002, 0.5)
SEGMENT_LENGTH_RANGE_M = (0.001, 1.0)
POSITION_LIMIT_M = 1.0  # |each coordinate| of a marker's centre in its component's frame
ANGLE_LIMIT_RAD = 10.0
PLANAR_TOLERANCE_RANGE_RAD = (0.0, 0.5)
DEFAULT_PLANAR_TOLERANCE_RAD = 0.05  # about 2.9°: smaller tilts are not told apart from a planar link
MAX_JOINTS = 100
_TOP_KEYS = (
    "dictionary",
    "marker_length_m",
    "segment_lengths_m",
    "components",
    "planar_tolerance_rad",
    "corner_refinement",
)
_COMPONENT_KEYS = ("name", "marker_id", "xyz_m", "rpy_rad", "marker_length_m")


class CornerRefinement(StrEnum):
    """How a marker's corners are refined: `edges` (the default) or one of ArUco's own.

    `edges`: lines fitted to the marker's four edges (`rig.hw.camera.edges`); the others are
    cv2.aruco.CORNER_REFINE_* (`subpix` with a fixed 5 × 5 px window).
    """

    EDGES = "edges"
    SUBPIX = "subpix"
    CONTOUR = "contour"
    APRILTAG = "apriltag"
    NONE = "none"


@dataclass(frozen=True)
class ComponentMarker:
    """One component's marker: its id and the pose of the marker's frame in the component's frame.

    The marker's frame is OpenCV's: origin at the centre of the black square, x to the right and y
    up as the marker is printed, z out of the printed face.
    """

    component: int  # 0 = the clamped base
    name: str
    marker_id: int
    pose_in_component: NDArray[np.float64]  # (4, 4)
    marker_length_m: float  # its black square's side: its own, or the map's `marker_length_m`


@dataclass(frozen=True)
class MarkerMap:
    """A validated marker map: see the module docstring and docs/formats.md §9.2."""

    source: str
    dictionary: str
    marker_length_m: float  # the side of every marker that does not give its own
    segment_lengths_m: tuple[float, ...]
    components: tuple[ComponentMarker, ...]
    planar_tolerance_rad: float = DEFAULT_PLANAR_TOLERANCE_RAD
    corner_refinement: CornerRefinement = CornerRefinement.EDGES

    @property
    def joint_count(self) -> int:
        """Number of joints J (one fewer than the components)."""
        return len(self.segment_lengths_m)

    def component_of_marker(self) -> dict[int, ComponentMarker]:
        """The components by their marker id."""
        return {c.marker_id: c for c in self.components}


def parse_marker_map(data: object, source: str) -> MarkerMap:
    """Validate a parsed marker map; `ConfigError` naming `source` and the field on any problem."""
    top = Section(data, source)
    top.reject_unknown(_TOP_KEYS)
    dictionary = top.string("dictionary", choices=sorted(DICTIONARY_SIZES))
    length_lo, length_hi = MARKER_LENGTH_RANGE_M
    length_m = top.number("marker_length_m", min_value=length_lo, max_value=length_hi)
    lo, hi = SEGMENT_LENGTH_RANGE_M
    segments = top.numbers("segment_lengths_m", max_length=MAX_JOINTS, min_value=lo, max_value=hi)
    items = top.sequence("components", min_length=2, max_length=MAX_JOINTS + 1)
    if len(items) != len(segments) + 1:
        raise top.error(
            "components",
            f"{len(items)} components for {len(segments)} segment lengths; allowed: one component per "
            f"segment plus the base ({len(segments) + 1})",
        )
    size = DICTIONARY_SIZES[dictionary]
    components: list[ComponentMarker] = []
    seen: dict[int, int] = {}
    for index, item in enumerate(items):
        sec = Section(item, source, f"components[{index}]")
        sec.reject_unknown(_COMPONENT_KEYS)
        marker_id = sec.integer("marker_id", min_value=0, max_value=size - 1)
        if marker_id in seen:
            raise sec.error(
                "marker_id", f"{marker_id} is also component {seen[marker_id]}'s; allowed: one marker per id"
            )
        seen[marker_id] = index
        name = sec.string("name", default="base" if index == 0 else f"component {index}")
        xyz = sec.numbers("xyz_m", length=3, min_value=-POSITION_LIMIT_M, max_value=POSITION_LIMIT_M)
        rpy = sec.numbers("rpy_rad", length=3, min_value=-ANGLE_LIMIT_RAD, max_value=ANGLE_LIMIT_RAD)
        own_length_m = sec.number(
            "marker_length_m",
            default=length_m,
            min_value=MARKER_LENGTH_RANGE_M[0],
            max_value=MARKER_LENGTH_RANGE_M[1],
        )
        components.append(ComponentMarker(index, name, marker_id, pose_from_xyz_rpy(xyz, rpy), own_length_m))
    lo, hi = PLANAR_TOLERANCE_RANGE_RAD
    tolerance = top.number(
        "planar_tolerance_rad", default=DEFAULT_PLANAR_TOLERANCE_RAD, min_value=lo, max_value=hi
    )
    refinement = top.string(
        "corner_refinement",
        default=CornerRefinement.EDGES.value,
        choices=[c.value for c in CornerRefinement],
    )
    return MarkerMap(
        source=source,
        dictionary=dictionary,
        marker_length_m=length_m,
        segment_lengths_m=tuple(segments),
        components=tuple(components),
        planar_tolerance_rad=tolerance,
        corner_refinement=CornerRefinement(refinement),
    )


def load_marker_map(path: str | os.PathLike[str]) -> MarkerMap:
    """Read and validate a marker map file (YAML)."""
    return parse_marker_map(load_yaml_file(path, what="a marker map (YAML)"), str(Path(path)))
