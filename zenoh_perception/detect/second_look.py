"""A second look at a whole frame for markers OpenCV's default read misses.

OpenCV's default parameters threshold the frame with windows of 3, 13 and 23 pixels. A marker
of 8-24 px often has too few pixels per cell for any of them to separate its cells, and a
blurred one of any size too soft an edge. Read at twice its size with the one window of
:data:`WINDOW_PX`, the same frame gives OpenCV what it needs for many of them: it finds markers
there that its default read misses, with OpenCV still deciding every id (the caller's veto
judges each one as it judges every other).

The look costs about four default reads of the frame, so it is taken only where it can pay:

- on frames up to :data:`MAX_SIDE_PX` a side (an HD720 frame read at 2x would cost several
  times a frame's budget);
- on the stream's first frame and every :data:`PERIOD` frames after, when the default read
  found fewer markers than on the frame before (one may have left its reach), and on the
  frame after a look that added a marker (to follow it while only the look reads it).

Where the default read found a marker larger than :data:`SMALL_SIDE_PX` (mean side), the
frame's tag goes to the closest marker that read found, without waiting: the look is then
taken :data:`LATER`, after the tag is out, for the frame's other detections. Elsewhere it is
taken :data:`NOW`, and what it finds may be the frame's tag.

What it finds is merged where no marker of the same id is at that place, and only where the
light around the marker reads like a printed marker's margin (:data:`QUIET_MIN`): the look
reads things the default read rightly passes over, and the generator's look-alikes it reads
sit on darker surrounds than any true marker it added on the real corpus. Pure: no Zenoh, no
logging.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_dictionary, detections_from_opencv
from zenoh_perception.detect.regions import same_marker
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import read_detection
from zenoh_perception.tags.geometry import mean_side

#: Frames with a larger side are not looked at again.
MAX_SIDE_PX: Final = 1000
#: How much larger the frame is read.
SCALE: Final = 2
#: The one adaptive-threshold window of the look, pixels of the enlarged frame.
WINDOW_PX: Final = 13
#: A frame where the default read found a marker larger than this (mean side, frame pixels)
#: has its tag without waiting for the look.
SMALL_SIDE_PX: Final = 32.0
#: The least quiet-zone reading (the ring around the marker against its white cells,
#: :attr:`~zenoh_perception.detect.verify.Reading.quiet`) of a marker the look adds. The
#: markers it added on the real corpus read 0.87 and up, on generated frames 0.77 and up; the
#: generated look-alikes it read and the veto kept, 0.35-0.85 (8 of 10 under 0.7). The veto's
#: own bound, for every marker, is 0.35.
QUIET_MIN: Final = 0.7
#: Every how many frames the look is taken when nothing changed.
PERIOD: Final = 8
#: :meth:`SecondLook.due`: look before the frame's tag is chosen, or after it is out.
NOW: Final = "now"
LATER: Final = "later"


class SecondLook:
    """The look of one stream (see the module documentation): :meth:`due` says whether and
    when a frame gets it, :meth:`look` takes it. ``counters`` count frames looked at and
    markers added."""

    def __init__(self, dictionaries: Sequence[str]) -> None:
        params = cv2.aruco.DetectorParameters()
        params.adaptiveThreshWinSizeMin = WINDOW_PX
        params.adaptiveThreshWinSizeMax = WINDOW_PX
        self._dictionaries = tuple(dictionaries)
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(self._dictionaries[0]), params)
        if len(self._dictionaries) > 1:
            self._detector.setDictionaries([aruco_dictionary(d) for d in self._dictionaries])
        self._frames = 0
        self._previous = 0
        self._added = False  # the last look added a marker
        self.counters: dict[str, int] = {"looks": 0, "added": 0}

    def due(self, shape: tuple[int, ...], found: Sequence[Detection]) -> str | None:
        """When the frame of ``shape`` whose default read found ``found`` gets the look:
        :data:`NOW`, :data:`LATER` or None (not at all); counts the frame."""
        index, previous = self._frames, self._previous
        self._frames, self._previous = index + 1, len(found)
        if max(shape[:2]) > MAX_SIDE_PX:
            self._added = False
            return None
        if not (index % PERIOD == 0 or len(found) < previous or self._added):
            return None
        if any(mean_side(d.corners) > SMALL_SIDE_PX for d in found):
            return LATER
        return NOW

    def look(
        self,
        image: npt.NDArray[np.uint8],
        found: list[Detection],
        keep: Callable[[npt.NDArray[np.float32]], bool] = lambda _: True,
    ) -> list[Detection]:
        """``found`` and the markers the enlarged ``image`` shows that no marker of ``found``
        is (same id, same place) and ``keep`` accepts (by their corners)."""
        self.counters["looks"] += 1
        self._added = False
        height, width = image.shape[:2]
        big = cv2.resize(image, (width * SCALE, height * SCALE), interpolation=cv2.INTER_LINEAR)
        if len(self._dictionaries) == 1:
            corners, ids, _rejected = self._detector.detectMarkers(big)
            more = detections_from_opencv(corners, ids, (0, 0), self._dictionaries)
        else:
            corners, ids, _rejected, indices = self._detector.detectMarkersMultiDict(big)
            more = detections_from_opencv(corners, ids, (0, 0), self._dictionaries, indices)
        merged = list(found)
        for detection in more:
            # the centre of the enlarged frame's pixel (x, y) is the frame's (x + 0.5) / 2 - 0.5
            quad = (detection.corners + np.float32(0.5)) / np.float32(SCALE) - np.float32(0.5)
            small = Detection(detection.tag_id, quad, detection.dictionary)
            if not keep(quad) or read_detection(image, small, small.dictionary).quiet < QUIET_MIN:
                continue
            if not any(same_marker(small, other) for other in merged):
                merged.append(small)
                self.counters["added"] += 1
                self._added = True
        return merged
