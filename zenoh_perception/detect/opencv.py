"""``cv2.aruco.ArucoDetector`` with OpenCV's default parameters: the reference every other
detector of this package is held to."""

from __future__ import annotations

from time import perf_counter
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.grids import GridKeeper
from zenoh_perception.detect.types import (
    Detection,
    Detector,
    Due,
    Looker,
    dictionary_name,
    dictionary_names,
)


def aruco_dictionary(name: str) -> Any:
    """The predefined ``cv2.aruco.Dictionary`` called ``name`` (case-insensitive).

    Raises:
        SettingsError: ``name`` is not a predefined dictionary.

    """
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary_name(name)))


#: cv2.cornerSubPix's stop: 10 iterations or a move under 0.05 px.
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 10, 0.05)


def set_opencv_threads(threads: int) -> None:
    """The process's OpenCV threads (``opencv_threads``; 0: OpenCV's choice): set once, when a
    process that detects starts (the service, a child process of the frame deadline), and
    never changed while it runs: the count is process-wide, and several streams' workers may
    be inside OpenCV at once."""
    if threads > 0:
        cv2.setNumThreads(threads)


def detections_from_opencv(
    corners: Any,
    ids: Any,
    offset: tuple[int, int] = (0, 0),
    dictionaries: tuple[str, ...] = ("",),
    indices: Any = None,
) -> list[Detection]:
    """``detectMarkers`` output as :class:`Detection` objects, shifted by ``offset`` (x, y):
    the top-left pixel of the region the detector ran on. Each is named after its entry of
    ``dictionaries``: the first, or the one ``indices`` (``detectMarkersMultiDict``'s) gives."""
    if ids is None or len(ids) == 0:
        return []
    shift = np.asarray(offset, dtype=np.float32)
    flat = np.asarray(ids).reshape(-1)
    which = np.zeros(len(flat), int) if indices is None else np.asarray(indices).reshape(-1)
    return [
        Detection(
            int(tag_id),
            np.asarray(quad, dtype=np.float32).reshape(4, 2) + shift,
            dictionaries[int(index)],
        )
        for tag_id, quad, index in zip(flat, corners, which, strict=True)
    ]


def aruco_detector(dictionaries: tuple[str, ...], params: cv2.aruco.DetectorParameters) -> Any:
    """OpenCV's ``ArucoDetector`` of ``dictionaries`` (canonical names, one or more) with
    ``params``."""
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionaries[0]), params)
    if len(dictionaries) > 1:
        detector.setDictionaries([aruco_dictionary(d) for d in dictionaries])
    return detector


def read_markers(
    detector: Any, image: Any, dictionaries: tuple[str, ...], offset: tuple[int, int] = (0, 0)
) -> tuple[list[Detection], Any]:
    """What ``detector`` (made by :func:`aruco_detector` for ``dictionaries``) reads on
    ``image`` (see :func:`detections_from_opencv` for ``offset``), and the candidates it
    rejected (OpenCV's quads, in ``image``'s pixels)."""
    if len(dictionaries) == 1:
        corners, ids, rejected = detector.detectMarkers(image)
        return detections_from_opencv(corners, ids, offset, dictionaries), rejected
    corners, ids, rejected, indices = detector.detectMarkersMultiDict(image)
    return detections_from_opencv(corners, ids, offset, dictionaries, indices), rejected


class OpenCvDetector(Detector):
    """OpenCV's ArUco detector, with OpenCV's default parameters.

    ``dictionary`` is one dictionary or several separated by commas; several are read in one
    call (``detectMarkersMultiDict``: the candidate search is shared, each candidate's bits
    are matched against every dictionary) and each detection names its dictionary.
    """

    def __init__(
        self,
        dictionary: str = "DICT_4X4_50",
        *,
        wary: bool = False,
        second_look: Looker | None = None,
    ) -> None:
        params = cv2.aruco.DetectorParameters()
        self._params = params
        self._min_perimeter_rate = float(params.minMarkerPerimeterRate)
        self.dictionaries = dictionary_names(dictionary)
        self._detector = aruco_detector(self.dictionaries, params)
        #: periodic grids (checkerboards, tiled floors) painted over before a whole-frame read
        #: once a read proved expensive (see detect/grids.py); from the first read when
        #: ``wary`` (a detector replacing one whose read stalled)
        self.grids = GridKeeper(armed=wary)
        #: a second read of frames for markers the default read misses (see
        #: detect/second_look.py); None: OpenCV's default read alone
        self.second_look = second_look
        # the frame read last, what its read found and the candidates it rejected, when its
        # look comes after its tag
        self._later: tuple[npt.NDArray[np.uint8], list[Detection], Any] | None = None
        self._rejected: Any = ()  # the candidates the last read rejected (OpenCV's quads)

    def _detect(self, image: npt.NDArray[np.uint8], offset: tuple[int, int]) -> list[Detection]:
        found, self._rejected = read_markers(self._detector, image, self.dictionaries, offset)
        return found

    def detect(
        self, gray: npt.NDArray[np.uint8], min_perimeter_px: float = 0.0, *, frame: bool = True
    ) -> list[Detection]:
        """Markers in the whole image; with ``min_perimeter_px``, none whose perimeter is
        shorter than that many pixels (never smaller than the configured rate allows).
        ``frame``: the image is a stream's frame (not a reduced copy of one), which the
        second look, when there is one, may read again."""
        self._set_min_perimeter(max(gray.shape[:2]), min_perimeter_px)
        image = self.grids.prepare(gray)
        # OpenCV's read alone: the finder's own time must not keep it armed
        start = perf_counter()
        found = self._detect(image, (0, 0))
        seconds = perf_counter() - start
        candidates = len(found) + len(self._rejected)
        self.grids.record(seconds, gray.shape[0] * gray.shape[1], candidates)
        found = [d for d in found if self.grids.keep(d.corners)]
        self._later = None
        look = self.second_look
        if frame and look is not None:
            due = look.due(gray.shape, found)
            if due is Due.NOW:
                found = look.look(image, found, self.grids.keep, self._rejected)
            elif due is Due.LATER:
                self._later = (image, found, self._rejected)
        return found

    def look_again(self) -> list[Detection]:
        """What the second look adds to the frame read last, where its look was left until
        after the frame's tag (see detect/second_look.py); once per frame, [] otherwise."""
        later, self._later = self._later, None
        if later is None or self.second_look is None:
            return []
        image, found, rejected = later
        return self.second_look.look(image, found, self.grids.keep, rejected)[len(found) :]

    def detect_region(
        self,
        image: npt.NDArray[np.uint8],
        offset: tuple[int, int],
        scale: int = 1,
        frame_side: int = 0,
        min_perimeter_px: float = 0.0,
    ) -> list[Detection]:
        """Markers in ``image``, a region of a larger frame whose top-left pixel is ``offset``
        (x, y) there, in that frame's coordinates. ``image`` may be grey or BGR.

        With ``scale`` > 1 the region is read at 1/scale of its size (a large marker needs no
        more pixels to be read); its corners are then refined at full resolution by OpenCV's
        sub-pixel corner search in a window of the scale's size.

        ``frame_side`` (the larger side of the whole frame, pixels) keeps the whole frame's
        smallest marker: OpenCV sets it as a fraction of the image's larger side
        (``minMarkerPerimeterRate``), so a small region would otherwise take every speck of
        texture for a candidate, cost far more per pixel than the frame, and report markers
        smaller than a read of the whole frame would. ``min_perimeter_px`` (full-resolution
        pixels) raises that floor further: most of OpenCV's time goes to the contours just
        above it, so a region read for a marker of known size can skip the specks.
        """
        height, width = image.shape[:2]
        small = image
        if scale > 1:
            size = (max(1, width // scale), max(1, height // scale))
            small = np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), np.uint8)
        floor = max(self._min_perimeter_rate * frame_side, min_perimeter_px) / scale
        self._set_min_perimeter(max(small.shape[:2]), floor)
        if scale == 1:
            return self._detect(small, offset)
        found = self._detect(small, (0, 0))
        if not found:
            return []
        # back to full resolution, then OpenCV's sub-pixel corner refinement there
        quads = np.concatenate([d.corners for d in found]) * np.float32(scale)
        quads += np.float32((scale - 1) / 2)
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        window = (scale + 1, scale + 1)
        cv2.cornerSubPix(grey, quads, window, (-1, -1), _SUBPIX_CRITERIA)
        quads += np.asarray(offset, dtype=np.float32)
        return [
            Detection(d.tag_id, quads[4 * i : 4 * i + 4], d.dictionary) for i, d in enumerate(found)
        ]

    def _set_min_perimeter(self, image_side: int, floor_px: float) -> None:
        """``minMarkerPerimeterRate`` for an image whose larger side is ``image_side``: the
        configured rate, or higher so that no marker's perimeter is under ``floor_px``."""
        rate = max(self._min_perimeter_rate, floor_px / max(1, image_side))
        if rate != self._params.minMarkerPerimeterRate:
            self._params.minMarkerPerimeterRate = rate
            self._detector.setDetectorParameters(self._params)
