"""A whole-frame scan that reads fewer pixels than OpenCV's default and keeps its decisions.

OpenCV's default detector thresholds the frame with three window sizes (3, 13 and 23 px) and
looks for quads in each. This scan splits that work by what each window is for:

- the fine window (3 px) at full resolution, where small markers need every pixel;
- all three windows on a half-resolution copy (a quarter of the pixels), where the wider
  windows find the same larger or blurred quads they find at full resolution;
- every quad the half-resolution pass saw, read or not, is read again by OpenCV's default
  detector at full resolution in a region around it, so the id and corners reported are the
  ones OpenCV's default gives on the full frame there.
"""

from __future__ import annotations

from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.regions import Rect, around, merge, side
from zenoh_perception.detect.types import Detection

Gray = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float32]

#: Smallest margin around a half-resolution quad read again at full resolution, pixels.
MARGIN_PX: Final = 20.0


def _fine_parameters() -> Any:
    params = cv2.aruco.DetectorParameters()
    params.adaptiveThreshWinSizeMin = 3
    params.adaptiveThreshWinSizeMax = 3
    return params


class PyramidScan:
    """OpenCV's ArUco detector on a whole frame, by the fine window at full resolution and
    every window at half resolution (see the module documentation)."""

    def __init__(self, dictionary: str = "DICT_4X4_50") -> None:
        self._fine = OpenCvDetector(dictionary, _fine_parameters())
        self._default = OpenCvDetector(dictionary)

    def detect(self, gray: Gray) -> list[Detection]:
        return self.detect_with_rejected(gray)[0]

    def detect_with_rejected(self, gray: Gray) -> tuple[list[Detection], list[Quad]]:
        """Markers in ``gray``, and the quads seen but not read (full-resolution pixels)."""
        height, width = gray.shape[:2]
        found, rejected = self._fine.detect_with_rejected(gray)
        if width < 4 or height < 4:
            return found, rejected
        half: Gray = np.asarray(
            cv2.resize(gray, (width // 2, height // 2), interpolation=cv2.INTER_AREA), np.uint8
        )
        coarse, coarse_rejected = self._default.detect_with_rejected(half)
        hints = [d.corners * 2.0 + 0.5 for d in coarse] + [q * 2.0 + 0.5 for q in coarse_rejected]
        regions: list[Rect] = merge(
            [around(q, max(MARGIN_PX, 0.5 * side(q)), width, height) for q in hints]
        )
        for x0, y0, x1, y1 in regions:
            for detection in self._default.detect_region(gray[y0:y1, x0:x1], (x0, y0)):
                found = [d for d in found if not _same(d, detection)] + [detection]
        return found, rejected


def _same(a: Detection, b: Detection) -> bool:
    """One marker found twice: same id, centres closer than half its side."""
    if a.tag_id != b.tag_id:
        return False
    distance = float(np.linalg.norm(a.corners.mean(axis=0) - b.corners.mean(axis=0)))
    return distance < 0.5 * side(b.corners)
