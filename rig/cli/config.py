"""`rig config measure`: the link's configuration measured from camera images (ArUco markers)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from rig.cli.output import emit_json, format_table
from rig.hw.camera.calibration import load_calibration
from rig.hw.camera.marker_map import load_marker_map
from rig.hw.camera.measure import CameraMeasurement
from rig.hw.camera.source import CameraConfigurationSource, ImageFiles


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig config` and its subcommand `measure`."""
    parser = subparsers.add_parser(
        "config",
        help="link configurations: measure them from camera images (needs the camera extra)",
        description=(
            "Link configurations measured by the camera configuration source (pip install -e '.[camera]')."
        ),
    )
    commands = parser.add_subparsers(title="commands", metavar="COMMAND", parser_class=type(parser))
    measure = commands.add_parser(
        "measure",
        help="joint angles of the link in each image, from its ArUco markers",
        description=(
            "Measure each image: the pose of every component's marker (solvePnP, IPPE_SQUARE), the "
            "joint rotations between consecutive components, and the planar angle about y with its "
            "standard deviation (docs/formats.md §9.3). A component whose marker is not seen stops "
            "the command with exit 1, naming it."
        ),
    )
    measure.add_argument(
        "images", nargs="+", metavar="IMAGE", help="images of the link (the calibration's size)"
    )
    measure.add_argument(
        "--camera", type=Path, required=True, metavar="CAL", help="calibration (rig camera calibrate)"
    )
    measure.add_argument("--markers", type=Path, required=True, metavar="MAP", help="marker map (YAML)")
    measure.add_argument("--json", action="store_true", help="print the result as one JSON object")
    measure.set_defaults(handler=run_measure)


def _table(measurement: CameraMeasurement) -> str:
    rows = [
        [
            i + 1,
            f"{math.degrees(angle):+.2f}",
            f"{math.degrees(sd):.2f}",
            f"{math.degrees(tilt):.2f}",
            f"{gap * 1000:.1f}",
        ]
        for i, (angle, sd, tilt, gap) in enumerate(
            zip(
                measurement.planar_angles_rad,
                measurement.planar_angle_sd_rad,
                measurement.out_of_plane_rad,
                measurement.joint_gap_m,
                strict=True,
            )
        )
    ]
    headers = ["joint", "angle [deg]", "sd [deg]", "out of plane [deg]", "gap [mm]"]
    sides = [m.side_px for m in measurement.markers]
    planar = "planar" if measurement.planar else "NOT planar (out-of-plane angle above the map's tolerance)"
    return f"{measurement.source}: {planar}; markers {min(sides):.0f}-{max(sides):.0f} px\n" + format_table(
        headers, rows
    )


def run_measure(args: argparse.Namespace) -> int:
    """Measure every image; exit 2 on bad input, 1 when a marker is not seen."""
    calibration = load_calibration(args.camera)
    marker_map = load_marker_map(args.markers)
    source = CameraConfigurationSource(ImageFiles(args.images), calibration, marker_map)
    measurements = [source.measure_frame() for _ in args.images]
    if args.json:
        emit_json(
            {
                "camera": str(args.camera),
                "markers": str(args.markers),
                "measurements": [m.as_dict() for m in measurements],
            }
        )
        return 0
    print("\n\n".join(_table(m) for m in measurements))
    return 0
