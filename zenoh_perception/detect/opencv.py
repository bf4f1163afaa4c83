"""``cv2.aruco.ArucoDetector`` with OpenCV's default parameters: the reference every other
detector of this package is held to."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.types import Detection, dictionary_name


def aruco_dictionary(name: str) -> Any:
    """The predefined ``cv2.aruco.Dictionary`` called ``name`` (case-insensitive).

    Raises:
        SettingsError: ``name`` is not a predefined dictionary.

    """
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary_name(name)))


def detections_from_opencv(
    corners: Any, ids: Any, offset: tuple[int, int] = (0, 0)
) -> list[Detection]:
    """``detectMarkers`` output as :class:`Detection` objects, shifted by ``offset`` (x, y):
    the top-left pixel of the region the detector ran on."""
    if ids is None or len(ids) == 0:
        return []
    shift = np.asarray(offset, dtype=np.float32)
    return [
        Detection(int(tag_id), np.asarray(quad, dtype=np.float32).reshape(4, 2) + shift)
        for tag_id, quad in zip(np.asarray(ids).reshape(-1), corners, strict=True)
    ]


class OpenCvDetector:
    """OpenCV's ArUco detector (default: OpenCV's default parameters) on every whole image."""

    def __init__(self, dictionary: str = "DICT_4X4_50", parameters: Any = None) -> None:
        params = parameters if parameters is not None else cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        return self.detect_region(gray, (0, 0))

    def detect_region(
        self, image: npt.NDArray[np.uint8], offset: tuple[int, int]
    ) -> list[Detection]:
        """Markers in ``image``, a region of a larger frame whose top-left pixel is ``offset``
        (x, y) there, in that frame's coordinates. ``image`` may be grey or BGR."""
        corners, ids, _rejected = self._detector.detectMarkers(image)
        return detections_from_opencv(corners, ids, offset)

    def detect_with_rejected(
        self, gray: npt.NDArray[np.uint8]
    ) -> tuple[list[Detection], list[npt.NDArray[np.float32]]]:
        """Markers in ``gray``, and the quads OpenCV considered but could not read (each
        (4, 2) float32)."""
        corners, ids, rejected = self._detector.detectMarkers(gray)
        quads = [np.asarray(q, dtype=np.float32).reshape(4, 2) for q in rejected]
        return detections_from_opencv(corners, ids), quads
