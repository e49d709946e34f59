"""Camera configuration source: joint-angle error against marker size in pixels, and time per frame.

Run: .venv/bin/python benchmarks/bench_camera.py [--scenes 8] [--repeats 5] [--seed 0]
     [--refinement subpix|contour|apriltag|none] [--choice chain|best] [--distances M ...]

Needs the camera extra (pip install -e '.[camera]'). Link 1 with the shipped marker map
(protocols/link1_markers.yaml: 18 mm markers) is rendered (rig/testing/camera_images.py) bent at
random within ±20° per joint, from distances of 0.2-0.75 m above its middle (the marker sides in
the table are the measured ones), by a 1280x960 camera with fx = 1000 px and mild distortion,
tilted up to ±8°, with blur σ 0.7 px, noise σ 2 grey levels and the partial occlusions of the
tests (the outer half of the white margin along one edge of three markers, part of an inner cell
of a fourth). Each image is measured with the exact calibration. Per distance: the RMS and the
95th percentile of |planar angle error| over all joints, the RMS of error / estimated sd (1 if the
estimated sd is right), images where a marker was not found, and images called non-planar.

Time per frame: the whole measurement (`measure_image`: detection, two pose solutions per marker,
the choice along the chain, joint rotations, uncertainty) against a plain `cv2.aruco` detection
(`ArucoDetector.detectMarkers` with the same parameters) of the same frame, each the median of
`--repeats` runs, interleaved; reported as a ratio and in ms.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time
from pathlib import Path

import numpy as np

from rig.hw.camera.marker_map import CornerRefinement, load_marker_map
from rig.hw.camera.measure import MarkerDetector, MarkerNotSeenError, measure_image, rotation_error_rad
from rig.testing.camera_images import SyntheticCamera
from rig.testing.camera_scenes import exact_calibration, random_scene

ROOT = Path(__file__).resolve().parent.parent
DISTANCES_M = (0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.75)  # nearer, the bent link leaves the image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8, help="images per distance (default 8)")
    parser.add_argument("--repeats", type=int, default=5, help="timing runs per image (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--refinement", default="subpix", choices=[c.value for c in CornerRefinement])
    parser.add_argument(
        "--choice",
        default="chain",
        choices=["chain", "best"],
        help="IPPE pose per marker: chosen along the chain (default) or each marker's best reprojection",
    )
    parser.add_argument("--distances", type=float, nargs="+", default=list(DISTANCES_M), metavar="M")
    args = parser.parse_args()

    marker_map = load_marker_map(ROOT / "protocols" / "link1_markers.yaml")
    marker_map = dataclasses.replace(marker_map, corner_refinement=CornerRefinement(args.refinement))
    camera = SyntheticCamera()
    detector = MarkerDetector(marker_map, exact_calibration(camera))
    print(
        f"link 1, 18 mm markers, corner refinement {args.refinement}, poses chosen by {args.choice}, "
        f"{args.scenes} images per distance"
    )
    header = (
        "distance m | side px | RMS deg | p95 deg | 3D RMS deg | RMS err/sd | not seen | non-planar | "
        "measure ms | detect ms | ratio"
    )
    print(header)
    print("-" * len(header))
    all_ratios: list[float] = []
    along_chain = args.choice == "chain"
    for distance in args.distances:
        errors: list[float] = []
        errors_3d: list[float] = []
        z_scores: list[float] = []
        sides: list[float] = []
        not_seen = non_planar = 0
        measure_s: list[float] = []
        detect_s: list[float] = []
        for index in range(args.scenes):
            scene = random_scene(marker_map, camera, distance, args.seed * 1000 + index)
            try:
                measured = measure_image(
                    detector, scene.image, source="bench", time_ns=0, along_chain=along_chain
                )
            except MarkerNotSeenError:
                not_seen += 1
                continue
            error = measured.planar_angles_rad - scene.angles_rad
            errors.extend(error)
            errors_3d.extend(
                rotation_error_rad(m, t[:3, :3])
                for m, t in zip(measured.joint_rotations, scene.transforms, strict=True)
            )
            z_scores.extend(error / measured.planar_angle_sd_rad)
            sides.extend(m.side_px for m in measured.markers)
            non_planar += not measured.planar
            one_measure, one_detect = [], []
            for _ in range(args.repeats):  # interleaved, so that load changes hit both alike
                t0 = time.perf_counter()
                measure_image(detector, scene.image, source="bench", time_ns=0, along_chain=along_chain)
                t1 = time.perf_counter()
                detector.detector.detectMarkers(scene.image)
                t2 = time.perf_counter()
                one_measure.append(t1 - t0)
                one_detect.append(t2 - t1)
            measure_s.append(statistics.median(one_measure))
            detect_s.append(statistics.median(one_detect))
        if not errors:
            print(f"{distance:10.2f} | markers not found in any image ({not_seen})")
            continue
        abs_deg = np.degrees(np.abs(errors))
        ratio = statistics.median(m / d for m, d in zip(measure_s, detect_s, strict=True))
        rms_deg = math.degrees(math.sqrt(np.mean(np.square(errors))))
        rms_3d_deg = math.degrees(math.sqrt(np.mean(np.square(errors_3d))))
        all_ratios.append(ratio)
        print(
            f"{distance:10.2f} | {np.mean(sides):7.1f} | {rms_deg:7.3f} | "
            f"{np.percentile(abs_deg, 95):7.3f} | {rms_3d_deg:10.3f} | "
            f"{math.sqrt(np.mean(np.square(z_scores))):10.2f} | "
            f"{not_seen:8d} | {non_planar:10d} | {1000 * statistics.median(measure_s):10.1f} | "
            f"{1000 * statistics.median(detect_s):9.1f} | {ratio:5.2f}"
        )
    if all_ratios:
        median_ratio = statistics.median(all_ratios)
        print(f"measurement time / plain detection time, median over distances: {median_ratio:.2f}")


if __name__ == "__main__":
    main()
