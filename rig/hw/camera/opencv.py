"""OpenCV, imported on first use: a missing or too old installation is an `InputError` naming the extra.

Every camera module calls `require_cv2()` inside its functions rather than importing cv2 at the
top, so that importing them (and `rig --help`) never needs the optional extra.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from rig.errors import InputError

EXTRA_HINT = "install the camera extra: pip install -e '.[camera]' (OpenCV >= 4.7)"


def require_cv2() -> ModuleType:
    """The `cv2` module with the ArUco API of OpenCV ≥ 4.7 (`cv2.aruco.ArucoDetector`), else InputError."""
    try:
        cv2 = importlib.import_module("cv2")
    except ImportError as exc:
        raise InputError(f"the camera needs OpenCV, which is not installed ({exc}); {EXTRA_HINT}") from None
    aruco = getattr(cv2, "aruco", None)
    if aruco is None or not hasattr(aruco, "ArucoDetector") or not hasattr(aruco, "CharucoDetector"):
        version = getattr(cv2, "__version__", "unknown")
        raise InputError(f"OpenCV {version} lacks cv2.aruco.ArucoDetector (added in 4.7); {EXTRA_HINT}")
    return cv2
