"""The camera configuration source: ArUco markers on the link's components, seen by a calibrated camera.

Optional: it needs OpenCV (`pip install -e '.[camera]'`), imported only when a camera is used
(`rig.hw.camera.opencv.require_cv2`), so the rest of the rig and `rig --help` work without it.
Formats and conventions: docs/formats.md §9.
"""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "camera_calibration",
    "marker_map",
    "measure",
    "opencv",
    "source",
]
