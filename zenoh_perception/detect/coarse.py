"""A coarse first read of a frame for its tag, before the whole frame is read.

With the area closeness the tag a rover steers by is the largest marker, and a large marker
needs few pixels to be found: OpenCV's read of the frame's first image-pyramid level (half its
size, :func:`cv2.pyrDown`) with one adaptive threshold (:data:`HALF_SIZE_WINDOW`) finds it
in about a sixth of the time of a whole read (a quarter-size level missed a 270 px tag under
motion blur; OpenCV's ArUco3 mode, which reads at the scale its smallest marker allows, was
no faster than the half-size read for the same smallest marker and found the tag less often:
docs/benchmarks.md). :class:`CoarseRead`
takes that read only where the stream's previous frame had its closest tag at least
:data:`GATE_SIDE_PX` across, looks only for markers of at least :data:`FLOOR_FRACTION` of that
side (most of OpenCV's time goes to the contours just above its smallest marker), and offers
a marker it found as the frame's tag only while nothing larger can have escaped it
(:meth:`CoarseRead.candidates`):

- it is at least :data:`TRUST_OVER_FLOOR` times that floor and :data:`TRUST_SIDE_PX` across;
- its area is at least :data:`AREA_MARGIN` times the next marker's (the order of two markers
  of about one size is left to the whole read);
- no tag of the frame before that this read missed could have grown past it
  (:data:`PREVIOUS_GROWTH`: a marker on a frame's border, or without a quiet zone, can escape
  a half-size read);
- a quad this read could not read, as large, holds no marker at full resolution (read again
  there, up to :data:`MAX_UNREAD` of them).

The marker offered is the one OpenCV's default read finds at full resolution in a crop
around it, with the corners the whole read gives it (the same pixels within reach of the
adaptive thresholds, and the same quads around it: :meth:`CoarseRead._crop_read`); the
caller refines them as it refines every marker's and lets the veto judge it on the
full-resolution frame. Each OpenCV read it takes runs under the frame deadline that bounds
the detector's reads (the caller's ``watched``, :meth:`~.types.Detector.watched`): one past
it is abandoned with its frame. After a slow read (:data:`SLOW_READ_S`), or one the deadline
abandoned, the stream's frames are read whole for a while.

On the approach sets and the corpus's videos the tag published from this read was the whole
read's in all but a few frames of thousands (docs/benchmarks.md, "Coarse first read for the
tag"). Pure: no Zenoh, no logging.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Final, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_detector, read_markers
from zenoh_perception.detect.types import Detection, R
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
#: How much larger (area) a tag may be than on the frame before: a tag that frame had and the
#: coarse read missed must be smaller than a marker offered by this factor (times
#: :data:`AREA_MARGIN`).
PREVIOUS_GROWTH: Final = 1.5
#: The half-size read's one adaptive-threshold window (pixels of the reduced image): where the
#: whole read's largest marker was 60 px or more, it found it as often as OpenCV's three
#: windows (3, 13, 23) in 2.7 times less time; 23 alone missed it twice as often
#: (docs/benchmarks.md).
HALF_SIZE_WINDOW: Final = 13
#: The crop a marker is read again in at full resolution: this many pixels around it (more
#: than half OpenCV's largest threshold window, 23 px) ...
CROP_MARGIN_PX: Final = 16.0
#: ... and this many of its sides (with 0.1 one marker of 4,796 came out otherwise than in the
#: whole read, with 0.2 none: docs/benchmarks.md).
CROP_MARGIN_SIDES: Final = 0.2
#: At most this many quads the coarse read could not read, as large as a marker it offers,
#: are read again at full resolution (each costs about a tenth of a whole read at HD720);
#: one more, and the frame is read whole.
MAX_UNREAD: Final = 2
#: The crop's read looks for markers of at least this fraction of the marker's side.
CROP_FLOOR: Final = 0.6
#: Two answers to ``tag`` are the same when their ids are, their centres are within this
#: (pixels) and ...
SAME_CENTRE_PX: Final = 0.5
#: ... their closeness within this.
SAME_CLOSENESS: Final = 0.002

#: A coarse read that took longer than this (seconds; 1-3 ms at HD720, 3-6 ms at HD1080 on
#: a quiet machine), or that the frame deadline abandoned, read a periodic pattern (a
#: checkerboard with cells just above its floor took it 0.2-0.9 s at HD720): the stream's
#: next :data:`REST_FRAMES` frames are read whole.
SLOW_READ_S: Final = 0.05
REST_FRAMES: Final = 300

Gray = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float32]
#: An OpenCV read's markers and the quads it rejected (:func:`read_markers`).
Markers = tuple[list[Detection], Any]
#: What OpenCV may raise on a frame it cannot read.
_READ_ERRORS: Final = (cv2.error, ValueError)


class Watch(Protocol):
    """Runs one read under the frame deadline (a detector's
    :meth:`~zenoh_perception.detect.types.Detector.watched`): its result, or None where the
    read is not taken. A read past the deadline does not return to the caller."""

    def __call__(self, read: Callable[[], R], /) -> R | None: ...


def unwatched(read: Callable[[], R]) -> R | None:
    """``read()``, without a deadline."""
    return read()


class CoarseRead:
    """The coarse first read of one stream (see the module documentation): :meth:`due` says
    whether a frame gets it, :meth:`candidates` takes it, :meth:`remember` is told each
    frame's answer."""

    def __init__(self, dictionaries: Sequence[str]) -> None:
        self._dictionaries = tuple(dictionaries)
        # a marker 1 px from the border of the reduced frame is 2-3 px from the frame's, which
        # the whole read may keep (its own bound is 3 px): the crop's read decides; one
        # adaptive threshold (HALF_SIZE_WINDOW), not OpenCV's three
        self._params = _params(
            minDistanceToBorder=1,
            adaptiveThreshWinSizeMin=HALF_SIZE_WINDOW,
            adaptiveThreshWinSizeMax=HALF_SIZE_WINDOW,
        )
        self._detector = aruco_detector(self._dictionaries, self._params)
        # A crop's read: OpenCV keeps of each group of nearby quads (a marker's contours at
        # its three thresholds, the paper's edge around it) the one of the longest perimeter,
        # and drops the whole group when that one is within minDistanceToBorder of the image's
        # border. A crop's side cuts the ground around the paper into quads that the whole
        # frame does not have, which would drop the marker's group that way: where the crop's
        # side is inside the frame, no distance to it is asked (0); where it is the frame's
        # own border, OpenCV's default (3 px), as in the whole read.
        self._crop_params = (_params(minDistanceToBorder=0), cv2.aruco.DetectorParameters())
        self._crop_detectors = tuple(
            aruco_detector(self._dictionaries, p) for p in self._crop_params
        )
        self._previous_side = 0.0  # the previous frame's closest tag, mean side (pixels)
        self._previous: dict[int, float] = {}  # the previous frame's tags: id -> area
        #: frames read coarsely, those whose tag came from that read, and slow reads (over
        #: :data:`SLOW_READ_S`, or abandoned at the frame deadline)
        self.counters: dict[str, int] = {"reads": 0, "answered": 0, "slow": 0}
        self._rest = 0  # frames still read whole after a slow coarse read
        # a read has started and not come back: if so when the next frame asks, the deadline
        # abandoned it (its thread never writes here again)
        self._in_flight = False

    def due(self) -> bool:
        """Whether the next frame is read coarsely first (counts the frame's rest, after a
        slow read)."""
        if self._in_flight:  # the last read was abandoned at the frame deadline
            self._in_flight = False
            self._slow()
        if self._rest > 0:
            self._rest -= 1
            return False
        return self._previous_side >= GATE_SIDE_PX

    def remember(self, side_px: float, tags: Sequence[tuple[int, float]] = ()) -> None:
        """The frame's closest tag had this mean side (pixels; 0: none), and its tags these
        ids and areas (pixels)."""
        self._previous_side = side_px
        self._previous = {}
        for tag_id, area in tags:
            self._previous[tag_id] = max(area, self._previous.get(tag_id, 0.0))

    def candidates(self, gray: Gray, watched: Watch = unwatched) -> Iterator[Detection]:
        """The markers of ``gray`` that may be its tag, largest first (none: read it whole),
        each as OpenCV's default reads it at full resolution. Only when :meth:`due`; each
        read at full resolution as it is asked for. Every OpenCV read runs under ``watched``
        (one it does not take ends the candidates)."""
        floor = max(FLOOR_PX, FLOOR_FRACTION * self._previous_side)
        read = self._watch(watched, lambda: self._half_size_read(gray, floor))
        if read is None:
            return
        (found, rejected), seconds = read
        if seconds > SLOW_READ_S:
            # a periodic pattern (a checkerboard, a tiled floor) with cells just above the
            # floor: the stream's next frames are read whole
            self._slow()
        found.sort(key=lambda d: polygon_area(d.corners), reverse=True)
        # a tag of the frame before it did not read may be there still, and have grown
        ids = {d.tag_id for d in found}
        missed = max(
            [a * PREVIOUS_GROWTH / 4.0 for i, a in self._previous.items() if i not in ids],
            default=0.0,
        )
        unread = _unread(rejected, found)
        least = max(TRUST_SIDE_PX, TRUST_OVER_FLOOR * floor) / 2.0
        looked = 0
        for index, detection in enumerate(found):
            after = found[index + 1].corners if index + 1 < len(found) else None
            area = polygon_area(detection.corners)
            if (
                mean_side(detection.corners) < least
                or area < AREA_MARGIN * missed
                or (after is not None and area < AREA_MARGIN * polygon_area(after))
            ):
                return
            # a quad OpenCV could not read at this size, about as large: read it at full
            # resolution as the whole read does (a marker there may be read, and be larger)
            while unread and area < AREA_MARGIN * polygon_area(unread[0]):
                looked += 1
                if looked > MAX_UNREAD:
                    return
                markers = self._crop_read(gray, unread.pop(0), watched)
                if markers is None or any(
                    polygon_area(m.corners) * AREA_MARGIN > 4.0 * area for m in markers
                ):
                    return
            full = self._full_resolution(gray, detection, watched)
            if full is None:
                return
            yield full

    def _watch(self, watched: Watch, read: Callable[[], R]) -> R | None:
        """``read`` under ``watched``; one that does not come back (abandoned at the frame
        deadline) is counted by the next :meth:`due`."""
        self._in_flight = True
        try:
            result = watched(read)
        except _READ_ERRORS:  # OpenCV failed on the frame: the read came back
            self._in_flight = False
            raise
        self._in_flight = False
        return result

    def _slow(self) -> None:
        """A slow read: the stream's next :data:`REST_FRAMES` frames are read whole."""
        self._rest = REST_FRAMES
        self.counters["slow"] += 1

    def _half_size_read(self, gray: Gray, floor: float) -> tuple[Markers, float]:
        """OpenCV's read of ``gray``'s first pyramid level for markers of at least ``floor``
        (pixels of the frame): what :func:`read_markers` gives, and the read's seconds."""
        self.counters["reads"] += 1
        small = np.asarray(cv2.pyrDown(gray), np.uint8)
        # no marker under the floor: its perimeter as a fraction of the reduced image's side
        _set_min_perimeter(self._detector, self._params, 2.0 * floor / max(small.shape[:2]))
        started = time.perf_counter()
        read = read_markers(self._detector, small, self._dictionaries)
        return read, time.perf_counter() - started

    def _full_resolution(
        self, gray: Gray, detection: Detection, watched: Watch
    ) -> Detection | None:
        """The marker ``detection`` (read on the first pyramid level of ``gray``) as OpenCV's
        default reads it at full resolution (:meth:`_crop_read`): the corners the whole read
        gives it. None where that read finds no marker of its id there, or is not taken."""
        corners = detection.corners * np.float32(2.0)
        side, centre = mean_side(corners), corners.mean(axis=0)
        for marker in self._crop_read(gray, detection.corners, watched) or ():
            near = float(np.linalg.norm(marker.corners.mean(axis=0) - centre)) < side / 4
            if near and marker.tag_id == detection.tag_id:
                return marker
        return None

    def _crop_read(self, gray: Gray, quad: Quad, watched: Watch) -> list[Detection] | None:
        """OpenCV's default read of ``gray`` at full resolution in a crop around ``quad``
        (corners on its first pyramid level, whose pixel (x, y) is centred on the frame's
        (2x, 2y)), for markers of at least :data:`CROP_FLOOR` of its side: the adaptive
        thresholds see there what they see in the whole read, and the quiet zone around a
        marker is in the crop (:data:`CROP_MARGIN_PX`, :data:`CROP_MARGIN_SIDES`), as are the
        quads OpenCV groups with it; none is dropped for its distance to the crop's sides
        inside the frame. Under ``watched``: None where the read is not taken."""
        corners = np.asarray(quad, np.float32).reshape(4, 2) * np.float32(2.0)
        side = mean_side(corners)
        margin = CROP_MARGIN_PX + CROP_MARGIN_SIDES * side
        height, width = gray.shape[:2]
        x0, y0 = np.maximum(np.floor(corners.min(axis=0) - margin), 0).astype(int)
        x1, y1 = np.ceil(corners.max(axis=0) + margin).astype(int) + 1
        crop = gray[y0 : min(y1, height), x0 : min(x1, width)]
        rate = 4.0 * CROP_FLOOR * side / max(crop.shape[:2])
        offset = (int(x0), int(y0))
        # a crop on the frame's border: OpenCV's 3 px, as the whole read asks it of that side
        # (asked of the crop's other sides too, it may drop the marker: the frame is then
        # read whole before its tag)
        edge = int(x0 == 0 or y0 == 0 or x1 >= width or y1 >= height)
        detector, params = self._crop_detectors[edge], self._crop_params[edge]

        def read() -> list[Detection]:
            _set_min_perimeter(detector, params, rate)
            return read_markers(detector, crop, self._dictionaries, offset)[0]

        return self._watch(watched, read)


def _unread(rejected: Sequence[Quad], found: Sequence[Detection]) -> list[Quad]:
    """The quads OpenCV ``rejected`` that are not part of a marker it ``found`` (their centre
    inside none), largest first."""
    quads = [np.asarray(q, np.float32).reshape(4, 2) for q in rejected]
    outside = [
        q
        for q in quads
        if not any(
            cv2.pointPolygonTest(d.corners, tuple(map(float, q.mean(axis=0))), False) >= 0
            for d in found
        )
    ]
    return sorted(outside, key=polygon_area, reverse=True)


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


def _params(**values: float) -> Any:
    """OpenCV's default ``DetectorParameters`` but for ``values``."""
    params = cv2.aruco.DetectorParameters()
    for name, value in values.items():
        setattr(params, name, value)
    return params


def _set_min_perimeter(detector: Any, params: Any, rate: float) -> None:
    """``detector``'s ``minMarkerPerimeterRate`` (of its ``params``) set to ``rate``."""
    if rate != params.minMarkerPerimeterRate:
        params.minMarkerPerimeterRate = rate
        detector.setDetectorParameters(params)
