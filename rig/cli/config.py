"""`rig config measure`: the link's configuration measured from camera images (ArUco markers)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.errors import ExitCode, InputError, RigError, one_line
from rig.hw.camera.camera_calibration import load_calibration
from rig.hw.camera.marker_map import load_marker_map
from rig.hw.camera.measure import CameraMeasurement, MarkerDetector, measure_image
from rig.hw.camera.source import read_grey_image


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig config` and its subcommand `measure`."""
    parser = subparsers.add_parser(
        "config",
        help=COMMANDS["config"],
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
            "standard deviation (docs/formats.md §9.3). Each image is measured or refused on its own "
            "(a component's marker not seen, an unreadable image, another size than the calibration's), "
            "naming the image and why; the exit status is 0 when every image was measured, 2 when "
            "any was not a valid image, else 1 when a marker was not seen in any."
        ),
    )
    measure.add_argument(
        "images", nargs="+", metavar="IMAGE", help="images of the link (the calibration's size)"
    )
    measure.add_argument(
        "--camera", type=Path, required=True, metavar="CAL", help="calibration (rig camera calibrate)"
    )
    measure.add_argument("--markers", type=Path, required=True, metavar="MAP", help="marker map (YAML)")
    measure.add_argument(
        "--json", action="store_true", help="print one JSON object: a result or an error per image"
    )
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


@dataclass(frozen=True)
class ImageOutcome:
    """One image of the call: measured, or refused with the reason and the exit status it asks for."""

    source: str
    measurement: CameraMeasurement | None
    error: str | None = None
    error_type: str | None = None  # MarkerNotSeenError, InputError
    exit_code: ExitCode = ExitCode.OK

    def as_dict(self) -> dict[str, object]:
        """The measurement's JSON (docs/formats.md §9.4), or `{"source", "error", "error_type"}`."""
        if self.measurement is not None:
            return self.measurement.as_dict()
        return {"source": self.source, "error": self.error, "error_type": self.error_type}

    def error_line(self) -> str:
        """The refusal as `rig` prints errors (docs: README, exit codes)."""
        kind = "error" if self.exit_code == ExitCode.INVALID_INPUT else self.error_type
        return f"rig: {kind}: {self.error}"


def _measure_one(detector: MarkerDetector, path: Path) -> ImageOutcome:
    try:
        image = read_grey_image(path)
        measurement = measure_image(detector, image, source=str(path), time_ns=time.time_ns())
    except InputError as exc:  # not an image, or not the calibration's size
        return ImageOutcome(str(path), None, one_line(str(exc)), type(exc).__name__, ExitCode.INVALID_INPUT)
    except RigError as exc:  # a marker not seen
        return ImageOutcome(str(path), None, one_line(str(exc)), type(exc).__name__, ExitCode.FAULT)
    return ImageOutcome(str(path), measurement)


def run_measure(args: argparse.Namespace) -> int:
    """Measure every image on its own; exit 2 on a bad file (or image), else 1 if a marker was not seen."""
    calibration = load_calibration(args.camera)
    marker_map = load_marker_map(args.markers)
    detector = MarkerDetector(marker_map, calibration)
    outcomes = [_measure_one(detector, Path(path)) for path in args.images]
    status = max((o.exit_code for o in outcomes), key=_severity)
    if args.json:
        emit_json(
            {
                "camera": str(args.camera),
                "markers": str(args.markers),
                "measured": sum(o.measurement is not None for o in outcomes),
                "refused": sum(o.measurement is None for o in outcomes),
                "measurements": [o.as_dict() for o in outcomes],
            }
        )
        return int(status)
    tables = [_table(o.measurement) for o in outcomes if o.measurement is not None]
    if tables:
        print("\n\n".join(tables))
    for outcome in outcomes:
        if outcome.error is not None:
            print(outcome.error_line(), file=sys.stderr)
    return int(status)


def _severity(code: ExitCode) -> int:
    """Invalid input outranks a marker not seen, which outranks success."""
    return {ExitCode.OK: 0, ExitCode.FAULT: 1, ExitCode.INVALID_INPUT: 2}[code]
