"""A coarse first read of a frame for its tag, before the whole frame is read.

With the area closeness the tag a rover steers by is the largest marker, and a large marker
needs few pixels to be found: OpenCV's default read of the frame's first image-pyramid level
(half its size, :func:`cv2.pyrDown`; a quarter for very large tags) finds it in a third of the
time of a whole read. :class:`CoarseRead` takes that read only where the stream's previous
frame had its closest tag at least :data:`GATE_SIDE_PX` across, looks only for markers of at
least :data:`FLOOR_FRACTION` of that side (most of OpenCV's time goes to the contours just
above its smallest marker), and offers the markers it found as the frame's tag only while
nothing larger can have escaped it (:meth:`CoarseRead.candidates`): each at least
:data:`TRUST_OVER_FLOOR` times that floor and :data:`TRUST_SIDE_PX` across, with an area at
least :data:`AREA_MARGIN` times the next one's (the order of two markers of about one size
is left to the whole read). Their corners come back to full resolution by OpenCV's sub-pixel
corner search there; the caller refines them further and lets the veto judge them on the
full-resolution frame, as every marker of a whole read.

On the approach set and the corpus's videos, the tag published from this read was the whole
read's in every frame measured (docs/benchmarks.md, "Coarse first read"). Pure: no Zenoh, no
logging.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_detector, read_markers
from zenoh_perception.detect.types import Detection
from zenoh_perception.tags.geometry import mean_side, polygon_area
from zenoh_perception.tags.selection import TagMessage

#: The previous frame's closest tag (mean side, pixels) from which a frame is read coarsely
#: first.
GATE_SIDE_PX: Final = 48.0
#: The smallest marker the coarse read looks for, as a fraction of the previous closest tag's
#: side (a tag shrinks by far less from one frame to the next).
FLOOR_FRACTION: Final = 0.4
#: ... and never under this (pixels of the frame), where a marker read at half size has too
#: few pixels a cell.
FLOOR_PX: Final = 20.0
#: A marker is offered as the tag only when at least this many times the floor: a marker
#: larger than it, read whole, is well within the coarse read's reach.
TRUST_OVER_FLOOR: Final = 1.5
#: ... and at least this across (pixels of the frame).
TRUST_SIDE_PX: Final = 40.0
#: A marker is offered only when its area is at least this many times the next largest one's
#: the coarse read found: their order cannot turn on the coarse corners' error.
AREA_MARGIN: Final = 1.15
#: From this previous side on (pixels), the frame is read at a quarter of its size.
QUARTER_SIDE_PX: Final = 1e9
#: Two answers to ``tag`` are the same when their ids are, their centres are within this
#: (pixels) and ...
SAME_CENTRE_PX: Final = 0.5
#: ... their closeness within this.
SAME_CLOSENESS: Final = 0.002
#: cv2.cornerSubPix's stop: 10 iterations or a move under 0.05 px.
_SUBPIX_CRITERIA: Final = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 10, 0.05)

Gray = npt.NDArray[np.uint8]


class CoarseRead:
    """The coarse first read of one stream (see the module documentation): :meth:`due` says
    whether a frame gets it, :meth:`candidates` takes it, :meth:`remember` is told each
    frame's answer."""

    def __init__(self, dictionaries: Sequence[str]) -> None:
        self._dictionaries = tuple(dictionaries)
        self._params = cv2.aruco.DetectorParameters()
        self._detector = aruco_detector(self._dictionaries, self._params)
        self._previous_side = 0.0  # the previous frame's closest tag, mean side (pixels)
        #: frames read coarsely, and those whose tag came from that read
        self.counters: dict[str, int] = {"reads": 0, "answered": 0}

    def due(self) -> bool:
        """Whether the next frame is read coarsely first."""
        return self._previous_side >= GATE_SIDE_PX

    def remember(self, side_px: float) -> None:
        """The frame's closest tag had this mean side (pixels; 0: none)."""
        self._previous_side = side_px

    def candidates(self, gray: Gray) -> list[Detection]:
        """The markers of ``gray`` that may be its tag, largest first (none: read it whole),
        their corners at full resolution. Only when :meth:`due`."""
        self.counters["reads"] += 1
        previous = self._previous_side
        floor = max(FLOOR_PX, FLOOR_FRACTION * previous)
        scale = 4 if previous >= QUARTER_SIDE_PX else 2
        small = _reduced(gray, scale)
        # no marker under the floor: its perimeter as a fraction of the reduced image's side
        rate = 4.0 * floor / scale / max(small.shape[:2])
        if rate != self._params.minMarkerPerimeterRate:
            self._params.minMarkerPerimeterRate = rate
            self._detector.setDetectorParameters(self._params)
        found, rejected = read_markers(self._detector, small, self._dictionaries)
        # a quad OpenCV could not read at this size may be a marker the whole read reads
        unread = max((polygon_area(np.reshape(q, (4, 2))) for q in rejected), default=0.0)
        found.sort(key=lambda d: polygon_area(d.corners), reverse=True)
        trusted: list[Detection] = []
        least = max(TRUST_SIDE_PX, TRUST_OVER_FLOOR * floor) / scale
        for index, detection in enumerate(found):
            after = found[index + 1].corners if index + 1 < len(found) else None
            area = polygon_area(detection.corners)
            if (
                mean_side(detection.corners) < least
                or area < AREA_MARGIN * unread
                or (after is not None and area < AREA_MARGIN * polygon_area(after))
            ):
                break
            trusted.append(detection)
        return [_full_resolution(gray, d, scale) for d in trusted]


def same_answer(published: TagMessage, whole: TagMessage) -> bool:
    """Whether two answers to ``tag`` are the same (:data:`SAME_CENTRE_PX`,
    :data:`SAME_CLOSENESS`)."""
    if published.tag_id != whole.tag_id:
        return False
    dx = published.x_tag_center_pixel - whole.x_tag_center_pixel
    dy = published.y_tag_center_pixel - whole.y_tag_center_pixel
    return bool(
        dx * dx + dy * dy <= SAME_CENTRE_PX**2
        and abs(published.closeness_metric - whole.closeness_metric) <= SAME_CLOSENESS
    )


def _reduced(gray: Gray, scale: int) -> Gray:
    """``gray`` at 1/``scale`` of its size (2 or 4): image-pyramid levels."""
    small = np.asarray(cv2.pyrDown(gray), np.uint8)
    if scale == 4:
        small = np.asarray(cv2.pyrDown(small), np.uint8)
    return small


def _full_resolution(gray: Gray, detection: Detection, scale: int) -> Detection:
    """``detection``, read on ``gray`` reduced ``scale`` times, with its corners in
    ``gray``'s pixels (a pyramid level's pixel (x, y) is centred on the frame's
    (x * scale, y * scale)) and found again there by OpenCV's sub-pixel corner search."""
    corners = np.ascontiguousarray(detection.corners * np.float32(scale), np.float32)
    window = (scale + 1, scale + 1)
    cv2.cornerSubPix(gray, corners, window, (-1, -1), _SUBPIX_CRITERIA)
    return Detection(detection.tag_id, corners, detection.dictionary)
