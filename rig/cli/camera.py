"""`rig camera calibrate`: camera intrinsics from chessboard or ChArUco images, written as OpenCV YAML."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.errors import InputError
from rig.hw.camera.camera_calibration import Board, BoardKind, calibrate, check_board, write_calibration
from rig.hw.camera.marker_map import DICTIONARY_SIZES
from rig.hw.camera.source import read_grey_image


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig camera` and its subcommand `calibrate`."""
    parser = subparsers.add_parser(
        "camera",
        help=COMMANDS["camera"],
        description="Camera tools for measuring the link with ArUco markers (pip install -e '.[camera]').",
    )
    commands = parser.add_subparsers(title="commands", metavar="COMMAND", parser_class=type(parser))
    calib = commands.add_parser(
        "calibrate",
        help="camera intrinsics from images of a chessboard or ChArUco board",
        description=(
            "Find the board in each image, calibrate the camera (cv2.calibrateCamera) and write its "
            "matrix and distortion to --out as OpenCV FileStorage YAML (docs/formats.md §9.1), atomically: "
            "an interrupted run leaves no file. Images without the board are skipped and named; a view "
            "whose RMS reprojection error is above 5 times the median view's (and 0.25 px) is dropped "
            "and named, and the calibration with it shown too; at least 3 must show the board "
            "(15-25 views, tilted up to about 35 degrees and spread over the whole image, give a good "
            "calibration)."
        ),
    )
    calib.add_argument("images", nargs="+", metavar="IMAGE", help="images of the board (same size)")
    calib.add_argument("--board", required=True, choices=[k.value for k in BoardKind], help="the target")
    calib.add_argument(
        "--columns",
        type=int,
        required=True,
        help="chessboard: inner corners per row; charuco: squares per row",
    )
    calib.add_argument(
        "--rows",
        type=int,
        required=True,
        help="chessboard: inner corners per column; charuco: squares per column",
    )
    calib.add_argument("--square-m", type=float, required=True, help="side of one square [m]")
    calib.add_argument("--marker-m", type=float, default=None, help="charuco: side of one marker [m]")
    calib.add_argument(
        "--dictionary",
        default="DICT_5X5_100",
        choices=sorted(DICTIONARY_SIZES),
        metavar="DICT",
        help="charuco: the ArUco dictionary of the board's markers (default DICT_5X5_100)",
    )
    calib.add_argument(
        "--out", type=Path, required=True, metavar="CAL.yaml", help="calibration file to write"
    )
    calib.add_argument("--force", action="store_true", help="replace --out if it exists")
    calib.add_argument("--json", action="store_true", help="print the result as one JSON object")
    calib.set_defaults(handler=run_calibrate)


def run_calibrate(args: argparse.Namespace) -> int:
    """Calibrate from the images and write --out; exit 2 on bad input (nothing written)."""
    board = Board(
        kind=BoardKind(args.board),
        columns=args.columns,
        rows=args.rows,
        square_m=args.square_m,
        marker_m=args.marker_m if args.board == BoardKind.CHARUCO else None,
        dictionary=args.dictionary if args.board == BoardKind.CHARUCO else None,
    )
    check_board(board)
    if args.out.exists() and not args.force:  # refused before the work, not after it
        raise InputError(f"--out {args.out}: exists; allowed: a new file (or --force to replace it)")
    images = [(str(path), read_grey_image(path)) for path in args.images]
    result = calibrate(board, images)
    write_calibration(result.calibration, args.out, overwrite=args.force)
    cal = result.calibration
    cx, cy = cal.principal_point_px
    everything = result.with_dropped
    if args.json:
        emit_json(
            {
                "out": str(args.out),
                "board": cal.board,
                "image_width": cal.image_width,
                "image_height": cal.image_height,
                "camera_matrix": cal.camera_matrix,
                "distortion_coefficients": cal.distortion,
                "reprojection_error_px": cal.reprojection_error_px,
                "used": list(result.used),
                "skipped": list(result.skipped),
                "dropped": list(result.dropped),
                "outlier_threshold_px": result.outlier_threshold_px,
                "views": [
                    {"image": v.image, "rms_px": v.rms_px, "max_px": v.max_px, "dropped": v.dropped}
                    for v in result.views
                ],
                "with_dropped_views": None
                if everything is None
                else {
                    "camera_matrix": everything.camera_matrix,
                    "distortion_coefficients": everything.distortion,
                    "reprojection_error_px": everything.reprojection_error_px,
                },
            }
        )
        return 0
    rows = [
        ["fx, fy [px]", f"{cal.fx_px:.2f}, {cal.fy_px:.2f}"],
        ["cx, cy [px]", f"{cx:.2f}, {cy:.2f}"],
        ["distortion", " ".join(f"{d:.5g}" for d in cal.distortion)],
        ["reprojection error [px]", f"{cal.reprojection_error_px:.3f} (RMS)"],
        [
            "views",
            f"{len(result.used)} used, {len(result.dropped)} dropped as outliers, "
            f"{len(result.skipped)} without the board",
        ],
    ]
    if everything is not None:
        ecx, ecy = everything.principal_point_px
        rows += [
            ["with the dropped views: fx, fy", f"{everything.fx_px:.2f}, {everything.fy_px:.2f}"],
            ["with the dropped views: cx, cy", f"{ecx:.2f}, {ecy:.2f}"],
            ["with the dropped views: error", f"{everything.reprojection_error_px:.3f} (RMS)"],
        ]
    print(format_table(["calibration", f"{cal.image_width}x{cal.image_height} px, {cal.board}"], rows))
    views = [
        [v.image, f"{v.rms_px:.3f}", f"{v.max_px:.3f}", "dropped" if v.dropped else "used"]
        for v in result.views
    ]
    print(format_table(["view", "RMS error [px]", "max [px]", ""], views))
    for view in result.views:
        if view.dropped:
            print(
                f"dropped (RMS reprojection error {view.rms_px:.3f} px, above "
                f"{result.outlier_threshold_px:.3f} px): {view.image}",
                file=sys.stderr,
            )
    for name in result.skipped:
        print(f"skipped (board not found): {name}", file=sys.stderr)
    print(f"wrote {args.out}")
    return 0
