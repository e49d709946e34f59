"""The camera configuration source: ArUco markers on the link's components, seen by a calibrated camera.

Optional: it needs OpenCV (`pip install -e '.[camera]'`), imported only when a camera is used
(`rig.hw.camera.opencv.require_cv2`), so the rest of the rig and `rig --help` work without it.
Formats and conventions: docs/formats.md §9.
"""
