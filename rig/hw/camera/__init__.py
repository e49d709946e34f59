"""The camera configuration source: ArUco markers on the link's components, seen by a calibrated camera.

Optional: it needs OpenCV (`pip install -e '.[camera]'`), imported only when a camera is used
(`rig.hw.camera.opencv.require_cv2`), so the rest of the rig and `rig --help` work without it.
Formats and conventions: docs/formats.md §9.
"""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "camera_calibration",
    "marker_map",
    "measure",
    "opencv",
    "source",
)

# The names users import (`from rig.hw.camera import CameraCalibration`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "CameraCalibration": "camera_calibration",
    "CameraConfigurationSource": "source",
    "MarkerMap": "marker_map",
    "require_cv2": "opencv",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
