"""ArUco marker detection on grey images (OpenCV's cv2.aruco.ArucoDetector)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.errors import SettingsError

if TYPE_CHECKING:  # (the colour check's module imports this one)
    from zenoh_perception.detect.colour import ColourLimits


@dataclass(frozen=True, slots=True)
class Detection:
    """One decoded marker: id and its four corners (float32, shape (4, 2)).

    Corner order is OpenCV's: top-left, top-right, bottom-right, bottom-left of the marker.
    """

    tag_id: int
    corners: npt.NDArray[np.float32]


class Detector(Protocol):
    """Anything that finds markers in a grey (single-channel uint8) image."""

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        """Return every marker found in ``gray``."""
        ...


@runtime_checkable
class ConvertingDetector(Protocol):
    """A detector that takes the colour frame and converts to grey only what it reads."""

    def detect_converting(
        self, pixels: npt.NDArray[np.uint8], code: int, colour: ColourLimits | None
    ) -> list[Detection]:
        """Return what ``detect(cv2.cvtColor(pixels, code))`` would, without the candidates
        that fail the colour check (:mod:`zenoh_perception.detect.colour`) within ``colour``
        (None: no colour check)."""
        ...


def dictionary_names() -> list[str]:
    """Names of OpenCV's predefined ArUco dictionaries (``DICT_4X4_50``, ...)."""
    return sorted(
        name
        for name in dir(cv2.aruco)
        if name.startswith("DICT_")
        and name.upper() == name
        and isinstance(getattr(cv2.aruco, name), int)
    )


def aruco_dictionary(name: str) -> Any:
    """The predefined ``cv2.aruco.Dictionary`` called ``name``.

    Raises:
        SettingsError: ``name`` is not a predefined dictionary.

    """
    key = name.upper()
    value = getattr(cv2.aruco, key, None) if key.startswith("DICT_") else None
    if not isinstance(value, int):
        msg = f"unknown ArUco dictionary {name!r}; choose one of {', '.join(dictionary_names())}"
        raise SettingsError(msg)
    return cv2.aruco.getPredefinedDictionary(value)


def detections_from_opencv(corners: Any, ids: Any) -> list[Detection]:
    """Convert ``detectMarkers`` output to :class:`Detection` objects."""
    if ids is None or len(ids) == 0:
        return []
    flat_ids = np.asarray(ids).reshape(-1)
    return [
        Detection(int(tag_id), np.asarray(quad, dtype=np.float32).reshape(4, 2))
        for tag_id, quad in zip(flat_ids, corners, strict=True)
    ]


class OpenCvDetector:
    """``cv2.aruco.ArucoDetector`` with the given (default: OpenCV's default) parameters.

    This is also the baseline the benchmark compares against.
    """

    def __init__(self, dictionary: str = "DICT_4X4_50", parameters: Any = None) -> None:
        params = parameters if parameters is not None else cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        corners, ids, _rejected = self._detector.detectMarkers(gray)
        return detections_from_opencv(corners, ids)


def make_detector(
    name: str, dictionary: str, *, full_scan_period: int = 8, scan_threads: int = 1
) -> Detector:
    """The detector called ``name`` ('fast' or 'opencv') for ``dictionary``.

    ``full_scan_period`` and ``scan_threads`` tune the fast detector (see fast_detector.py).

    Raises:
        SettingsError: unknown detector or dictionary.

    """
    if name == "opencv":
        return OpenCvDetector(dictionary)
    if name == "fast":
        # fast_detector builds on this module (Detection, aruco_dictionary): import it late
        from zenoh_perception.fast_detector import (  # noqa: PLC0415
            FastDetector,
            FastDetectorConfig,
        )

        config = FastDetectorConfig(full_scan_period=full_scan_period, scan_threads=scan_threads)
        return FastDetector(dictionary, config)
    msg = f"unknown detector {name!r}; choose 'fast' or 'opencv'"
    raise SettingsError(msg)
