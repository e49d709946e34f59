"""The camera configuration source (`rig.hw.seams.ConfigurationSource`) and where its frames come from.

Frames come from a camera device (`CameraDevice`, an OpenCV capture index) or from image files
(`ImageFiles`, one file per measurement, for offline measuring and tests). Each `measure()` takes
one frame and measures it (`rig.hw.camera.measure`); a component whose marker is not seen raises
`MarkerNotSeenError` naming it. Not verified on hardware: the device path is exercised here only
through its error handling; the image path by rendered images (tests/test_camera.py).
"""

from __future__ import annotations

import os
import stat
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from rig.errors import InputError, NotConnectedError
from rig.hw.camera.camera_calibration import CameraCalibration
from rig.hw.camera.marker_map import MarkerMap
from rig.hw.camera.measure import CameraMeasurement, MarkerDetector, measure_image
from rig.hw.camera.opencv import require_cv2
from rig.hw.seams import Clock, ConfigurationReading

MAX_IMAGE_BYTES = 200 * 1024 * 1024
DEVICE_INDEX_RANGE = (0, 63)
DEVICE_WARMUP_FRAMES = 3  # auto-exposure settles over the first frames of a freshly opened capture


@dataclass(frozen=True)
class Frame:
    """One grey image and where it came from."""

    source: str
    image: NDArray[np.uint8]


class FrameSource(Protocol):
    """Gives one frame per call."""

    def read(self) -> Frame:
        """The next frame; an error naming the device or file if there is none."""
        ...

    def close(self) -> None:
        """Release the device (nothing for files)."""
        ...


def read_grey_image(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """A grey 8-bit image from a file (PNG, JPEG, ...); InputError naming the file if it cannot be read."""
    cv2 = require_cv2()
    p = Path(path)
    try:
        info = os.stat(p)
    except OSError as exc:
        raise InputError(f"{p}: cannot be read ({exc.strerror}); allowed: an image file") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"{p}: not a regular file; allowed: an image file")
    if info.st_size > MAX_IMAGE_BYTES:
        raise InputError(
            f"{p}: {info.st_size} bytes; allowed: an image file of at most {MAX_IMAGE_BYTES} bytes"
        )
    data = np.fromfile(p, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if image is None:
        raise InputError(f"{p}: not an image OpenCV can decode; allowed: PNG, JPEG, TIFF, BMP, ...")
    return np.asarray(image, np.uint8)


class ImageFiles:
    """Frames from image files, in the order given; one file per `read()`."""

    def __init__(self, paths: Sequence[str | os.PathLike[str]]) -> None:
        if not paths:
            raise InputError("images: none given; allowed: one or more image files")
        self._paths = [Path(p) for p in paths]
        self._next = 0

    def read(self) -> Frame:
        """The next file's image; InputError once every file was read."""
        if self._next >= len(self._paths):
            raise InputError(
                f"images: all {len(self._paths)} were measured; allowed: one image per measurement"
            )
        path = self._paths[self._next]
        self._next += 1
        return Frame(str(path), read_grey_image(path))

    def close(self) -> None:
        """Nothing to release."""


class CameraDevice:
    """Frames from a camera by OpenCV capture index (e.g. 0 for /dev/video0). Not verified on hardware."""

    def __init__(self, index: int) -> None:
        lo, hi = DEVICE_INDEX_RANGE
        if not lo <= index <= hi:
            raise InputError(f"camera device index {index}; allowed: {lo} to {hi}")
        cv2 = require_cv2()
        self._cv2 = cv2
        self._name = f"camera {index}"
        self._capture = cv2.VideoCapture(index)
        if not self._capture.isOpened():
            self._capture.release()
            raise NotConnectedError(f"{self._name}: cannot be opened (is it plugged in, and free?)")
        for _ in range(DEVICE_WARMUP_FRAMES):
            self._capture.read()

    def read(self) -> Frame:
        """A fresh grey frame; NotConnectedError if the camera gives none."""
        ok, image = self._capture.read()
        if not ok or image is None:
            raise NotConnectedError(f"{self._name}: gave no frame")
        if image.ndim == 3:
            image = self._cv2.cvtColor(image, self._cv2.COLOR_BGR2GRAY)
        return Frame(self._name, np.asarray(image, np.uint8))

    def close(self) -> None:
        """Release the capture."""
        self._capture.release()


class CameraConfigurationSource:
    """`ConfigurationSource` on a camera: one frame per `measure()`, measured by the marker map."""

    def __init__(
        self,
        frames: FrameSource,
        calibration: CameraCalibration,
        marker_map: MarkerMap,
        clock: Clock | None = None,
    ) -> None:
        self._frames = frames
        self._detector = MarkerDetector(marker_map, calibration)
        self._clock = clock
        self.last: CameraMeasurement | None = None

    def measure_frame(self) -> CameraMeasurement:
        """Measure the next frame, with per-joint uncertainty and diagnostics."""
        frame = self._frames.read()
        now = self._clock.time_ns() if self._clock is not None else time.time_ns()
        self.last = measure_image(self._detector, frame.image, source=frame.source, time_ns=now)
        return self.last

    def measure(self) -> ConfigurationReading:
        """The seam: the next frame's configuration (planar angles only when the link lies in a plane)."""
        return self.measure_frame().reading()

    def close(self) -> None:
        """Release the frame source."""
        self._frames.close()
