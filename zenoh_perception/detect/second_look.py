"""A second look at a frame for markers OpenCV's default read misses.

OpenCV's default parameters threshold the frame with windows of 3, 13 and 23 pixels and
correct no bit of a small dictionary's code. A marker of 8-24 px often has too few pixels per
cell for any window to separate its cells, or one cell read wrong, and a blurred one of any
size too soft an edge. Read again at twice its size, the same pixels give OpenCV what it needs
for many of them, with OpenCV still deciding every id (the caller's veto judges each one as it
judges every other). The look reads:

- **small frames** (up to :data:`MID_LINES` lines and :data:`MAX_SIDE_PX` a side) whole, at
  twice their size: up to :data:`LOW_RES_LINES` lines by :data:`LOW_RES_PASS` (windows of 9
  and 17 px, every correctable bit corrected: markers of 2-3 px a cell, a cell of which the
  default read often reads wrong), from there by :data:`MID_PASS` (one window of 13 px).
  Each pass was chosen from what OpenCV's own parameters read on the corpus per frame size
  (``python -m tools.passes``). That costs about four default reads of the frame, so it is
  taken on the stream's first frame and every :data:`PERIOD` frames after, when the default
  read found fewer markers than on the frame before (one may have left its reach), and on the
  frame after a look that added a marker (to follow it while only the look reads it); a
  low-resolution frame also whenever the default read found fewer markers than on any of the
  last :data:`PERIOD` frames (its markers of 2-3 px a cell come and go from frame to frame);
- **larger frames** (960x720, HD720 and up: no pass measured read a marker the default read
  missed on frames of over 480 lines, and a whole read at 2x would cost several times a
  frame's budget) only where the default read left a candidate: the quads OpenCV rejected,
  :data:`CANDIDATE_SIDE_PX` a side, the :data:`MAX_CANDIDATES` most like a printed marker
  (lighter around, dark and light inside), each cropped and read at twice its size with the
  windows of :data:`CANDIDATE_WINDOWS` and every correctable bit corrected. That costs a
  fraction of a frame's read, so it is also taken on every frame where the default read found
  no marker (a far tag the rover is looking for). A small frame's candidates are left: read so
  on the real corpus's small pictures, they gave look-alikes the veto keeps.

Where the default read found a marker larger than :data:`SMALL_SIDE_PX` (mean side), the
frame's tag goes to the closest marker that read found, without waiting: the look is then
taken :data:`LATER`, after the tag is out, for the frame's other detections. Elsewhere it is
taken :data:`NOW`, and what it finds may be the frame's tag.

What it finds is merged where no marker of the same id is at that place, and only where the
light around the marker reads like a printed marker's margin (:data:`ADDED_QUIET_MIN`): the look
reads things the default read rightly passes over, and the generator's look-alikes it reads
sit on darker surrounds than any true marker it added on the real corpus. A candidate read
with corrected bits, and a marker of a correcting pass whose cells do not read as its id's
code bit for bit, must also be seen nearly face on (:data:`CORRECTED_MIN_SIDE_RATIO`) and
read as its id by a clear margin on the cells' own levels (:data:`CORRECTED_MARGIN_BITS`),
whatever its surround.
Pure: no Zenoh, no logging.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.cells import (
    Reading,
    decision_margin,
    dictionary_codes,
    id_code,
    quad_sides,
)
from zenoh_perception.detect.opencv import aruco_detector, read_markers
from zenoh_perception.detect.regions import same_marker
from zenoh_perception.detect.types import Detection, Due
from zenoh_perception.detect.verify import read_detection
from zenoh_perception.tags.geometry import mean_side

Quad = npt.NDArray[np.float32]

#: Frames with a longer side than this, or more lines than :data:`MID_LINES`, are read whole
#: by no pass: only where OpenCV rejected a candidate (see the module documentation).
MAX_SIDE_PX: Final = 1000
#: How much larger a pass reads the frame.
SCALE: Final = 2
#: Frames of at most this many lines (the shorter side: 320x180, 384x216, 320x240, 424x240)
#: are low-resolution frames: their markers have 2-3 px a cell, and they are read by
#: :data:`LOW_RES_PASS`, also whenever the default read found fewer markers than lately.
LOW_RES_LINES: Final = 240
#: Frames of more lines than this (960x720, 816x612, HD720 and up) are read whole by no pass:
#: on the corpus's stills and videos of 481-720 lines no setting measured read a marker the
#: default read missed (``python -m tools.passes``).
MID_LINES: Final = 480


@dataclass(frozen=True, slots=True)
class Pass:
    """One read of the whole frame by OpenCV's own detector with other parameters: the frame
    enlarged :data:`SCALE` times, its adaptive-threshold windows from, to, step (enlarged
    pixels), and whether every bit the dictionary can correct is corrected."""

    windows: tuple[int, int, int]
    corrects: bool = False

    def detector(self, dictionaries: Sequence[str]) -> Any:
        """OpenCV's detector for this pass, on ``dictionaries``."""
        params = cv2.aruco.DetectorParameters()
        first, last, step = self.windows
        params.adaptiveThreshWinSizeMin = first
        params.adaptiveThreshWinSizeMax = last
        params.adaptiveThreshWinSizeStep = step
        if self.corrects:
            params.errorCorrectionRate = 1.0
        return aruco_detector(tuple(dictionaries), params)


#: The pass of low-resolution frames (:data:`LOW_RES_LINES`), stills and video alike: windows
#: of 9 and 17 px at 2x, every correctable bit corrected. On the corpus's board video of
#: 320x180 (every 4th frame) it read 258 id-frames the default missed, against 180 without the
#: correction and 148 with the one 13 px window, at the cost of those; on its 320x240 stills 9
#: against 5; no false id either way, before the look's own checks and the veto; on generated
#: look-alikes of 320x240 and 320x180 it added none (``python -m tools.passes``).
LOW_RES_PASS: Final = Pass((9, 17, 8), corrects=True)
#: The pass of frames of 241-480 lines: the one window of 13 px at 2x. On the corpus's videos
#: of that size it read 10 id-frames the default missed (833 frames), on its stills 8 (17),
#: no false id; the windows 9 and 17 read 9 and 9 at 1.5x its cost; with every bit corrected
#: too, 18 and 13, but 9 false ids on the videos and, on generated look-alikes of 640x480, one
#: the veto keeps.
MID_PASS: Final = Pass((13, 13, 10))
#: A frame where the default read found a marker larger than this (mean side, frame pixels)
#: has its tag without waiting for the look.
SMALL_SIDE_PX: Final = 32.0
#: The least quiet-zone reading (the ring around the marker against its white cells,
#: :attr:`~zenoh_perception.detect.cells.Reading.quiet`) of a marker the look adds. The
#: markers it added on the real corpus read 0.87 and up, on generated frames 0.77 and up; the
#: generated look-alikes it read and the veto kept, 0.35-0.85 (8 of 10 under 0.7). The veto's
#: own bound, for every marker, is 0.35.
ADDED_QUIET_MIN: Final = 0.7
#: Every how many frames the look is taken when nothing changed.
PERIOD: Final = 8
#: The rejected candidates of a larger frame read again: mean side, frame pixels. Under 8 px
#: the veto's resolution rule judges; over 32 px a marker has pixels enough a cell.
CANDIDATE_SIDE_PX: Final = (8.0, 32.0)
#: At most this many candidates of a frame are read again (a cluttered HD720 frame leaves
#: 20-30 in that range; each read costs about 0.1 ms).
MAX_CANDIDATES: Final = 8
#: The candidates' adaptive-threshold windows: from, to, step (pixels of the enlarged crop).
CANDIDATE_WINDOWS: Final = (7, 23, 8)
#: The crop around a candidate: this many times its side each way from its centre, and 2 px.
CROP_SIDES: Final = 1.2
#: The least margin, in bits, by which a candidate read with corrected bits must read as its
#: id on the cells' own levels (the veto asks 0.5 of a marker on a surround unlike paper): on
#: generated HD720 frames at 8-16 m, the true tags the candidates added read 1.05 and up, the
#: one wrong id they read 0.61.
CORRECTED_MARGIN_BITS: Final = 1.0
#: The least ratio of its shortest side to its longest of a marker read with corrected bits:
#: one seen more than about 50° off face-on leaves its cells too few pixels across for a
#: corrected read to be trusted. The true tags the candidates added on generated HD720 (turned
#: up to 30°) are 0.70 and up; the look-alikes they read on a real carton photo, an outlined
#: box in a label and a stroke of a printed character, 0.41 and 0.30.
CORRECTED_MIN_SIDE_RATIO: Final = 0.6
#: :meth:`SecondLook.due`: look before the frame's tag is chosen, or after it is out.
NOW: Final = Due.NOW
LATER: Final = Due.LATER


def _likeness(image: npt.NDArray[np.uint8], quad: Quad, side: float) -> tuple[bool, float]:
    """How much ``quad`` looks like a printed marker, for ranking candidates: whether the band
    of about a cell around its box is lighter than the box's inside (paper around it), then
    the spread of the grey levels inside (a marker's cells are dark and light; a plain dark
    square, a hole or a shadow is even)."""
    cell = max(1, round(side / 6))
    x0, y0 = np.floor(quad.min(axis=0)).astype(int)
    x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
    inner = image[max(0, y0 + cell) : max(0, y1 - cell), max(0, x0 + cell) : max(0, x1 - cell)]
    box = image[max(0, y0) : y1, max(0, x0) : x1]
    outer = image[max(0, y0 - cell) : y1 + cell, max(0, x0 - cell) : x1 + cell]
    if inner.size == 0 or outer.size <= box.size:
        return False, 0.0
    ring = (float(outer.sum(dtype=np.int64)) - float(box.sum(dtype=np.int64))) / (
        outer.size - box.size
    )
    return ring > float(inner.mean()), float(inner.std())


class SecondLook:
    """The look of one stream (see the module documentation): :meth:`due` says whether and
    when a frame gets it, :meth:`look` takes it. ``counters`` count frames looked at,
    candidates read again and markers added."""

    def __init__(self, dictionaries: Sequence[str]) -> None:
        self._dictionaries = tuple(dictionaries)
        self._detectors = {
            chosen: chosen.detector(self._dictionaries) for chosen in (LOW_RES_PASS, MID_PASS)
        }
        params = cv2.aruco.DetectorParameters()
        first, last, step = CANDIDATE_WINDOWS
        params.adaptiveThreshWinSizeMin = first
        params.adaptiveThreshWinSizeMax = last
        params.adaptiveThreshWinSizeStep = step
        params.errorCorrectionRate = 1.0  # every bit the dictionary can correct
        params.minMarkerPerimeterRate = 0.5  # the crop is about 2.4 of its candidate's side
        self._candidate_detector = aruco_detector(self._dictionaries, params)
        self._codes = {name: dictionary_codes(name) for name in self._dictionaries}
        self._frames = 0
        self._previous = 0
        self._recent: list[int] = []  # markers the default read found, the last PERIOD frames
        self._added = False  # the last look added a marker
        self.counters: dict[str, int] = {"looks": 0, "candidates": 0, "added": 0}

    def due(self, shape: tuple[int, ...], found: Sequence[Detection]) -> Due | None:
        """When the frame of ``shape`` whose default read found ``found`` gets the look:
        :data:`NOW`, :data:`LATER` or None (not at all); counts the frame."""
        index, previous = self._frames, self._previous
        self._frames, self._previous = index + 1, len(found)
        most = max(self._recent, default=0)
        self._recent = [*self._recent[-(PERIOD - 1) :], len(found)]
        searching = not _whole(shape) and not found
        # a low-resolution frame where the default read found fewer markers than lately: one
        # it read lately may be there, too small or too soft for its windows this time
        short = min(shape[:2]) <= LOW_RES_LINES and len(found) < most
        if not (index % PERIOD == 0 or len(found) < previous or self._added or searching or short):
            return None
        if any(mean_side(d.corners) > SMALL_SIDE_PX for d in found):
            return LATER
        return NOW

    def look(
        self,
        image: npt.NDArray[np.uint8],
        found: list[Detection],
        keep: Callable[[Quad], bool] = lambda _: True,
        rejected: Sequence[npt.NDArray[np.float32]] = (),
    ) -> list[Detection]:
        """``found`` and the markers that no marker of ``found`` is (same id, same place) and
        ``keep`` accepts (by their corners): on a small ``image``, those the whole image shows
        enlarged; on a larger one, those its default read's ``rejected`` candidates show."""
        self.counters["looks"] += 1
        self._added = False
        if not _whole(image.shape):
            return self._merge(image, found, self._candidates(image, found, rejected), keep)
        chosen = LOW_RES_PASS if min(image.shape[:2]) <= LOW_RES_LINES else MID_PASS
        height, width = image.shape[:2]
        big = cv2.resize(image, (width * SCALE, height * SCALE), interpolation=cv2.INTER_LINEAR)
        more = [
            # the centre of the enlarged frame's pixel (x, y) is the frame's (x + 0.5) / 2 - 0.5
            (Detection(d.tag_id, _shrunk(d.corners, (0, 0)), d.dictionary), chosen.corrects)
            for d in read_markers(self._detectors[chosen], big, self._dictionaries)[0]
        ]
        return self._merge(image, found, more, keep, exact=True)

    def _candidates(
        self,
        image: npt.NDArray[np.uint8],
        found: list[Detection],
        rejected: Sequence[npt.NDArray[np.float32]],
    ) -> list[tuple[Detection, bool]]:
        """What the most marker-like of ``rejected`` read as, cropped and enlarged."""
        low, high = CANDIDATE_SIDE_PX
        centres = [(d.corners.mean(axis=0), mean_side(d.corners)) for d in found]
        ranked: list[tuple[tuple[bool, float], Quad, float]] = []
        for candidate in rejected:
            quad = np.asarray(candidate, np.float32).reshape(4, 2)
            side = mean_side(quad)
            centre = quad.mean(axis=0)
            if not low <= side <= high or any(
                float(np.linalg.norm(centre - c)) < max(side, s) for c, s in centres
            ):
                continue
            ranked.append((_likeness(image, quad, side), quad, side))
        ranked.sort(key=lambda r: r[0], reverse=True)
        height, width = image.shape[:2]
        more: list[tuple[Detection, bool]] = []
        for _rank, quad, side in ranked[:MAX_CANDIDATES]:
            self.counters["candidates"] += 1
            reach = side * CROP_SIDES + 2
            x0, y0 = np.maximum(np.floor(quad.mean(axis=0) - reach), 0).astype(int)
            x1 = min(width, int(np.ceil(quad[:, 0].mean() + reach)) + 1)
            y1 = min(height, int(np.ceil(quad[:, 1].mean() + reach)) + 1)
            crop = image[y0:y1, x0:x1]
            size = (crop.shape[1] * SCALE, crop.shape[0] * SCALE)
            big = cv2.resize(crop, size, interpolation=cv2.INTER_LINEAR)
            for d in read_markers(self._candidate_detector, big, self._dictionaries)[0]:
                more.append((Detection(d.tag_id, _shrunk(d.corners, (x0, y0)), d.dictionary), True))
        return more

    def _merge(
        self,
        image: npt.NDArray[np.uint8],
        found: list[Detection],
        more: list[tuple[Detection, bool]],
        keep: Callable[[Quad], bool],
        *,
        exact: bool = False,
    ) -> list[Detection]:
        """``found`` and each of ``more`` that is new, accepted by ``keep`` and on a light
        margin, and, when its bits may have been corrected (its flag), clear
        (:meth:`_clear`); with ``exact``, unless its cells read as its id's code bit for bit
        (nothing was corrected)."""
        merged = list(found)
        for detection, corrected in more:
            if not keep(detection.corners) or any(same_marker(detection, o) for o in merged):
                continue
            reading = read_detection(image, detection, detection.dictionary)
            if reading.quiet < ADDED_QUIET_MIN:
                continue
            trusted = not corrected or (exact and self._exact(reading, detection))
            if not trusted and not self._clear(reading, detection):
                continue
            merged.append(detection)
            self.counters["added"] += 1
            self._added = True
        return merged

    def _exact(self, reading: Reading, detection: Detection) -> bool:
        """Whether ``detection``'s cells (``reading``) read as its id's code bit for bit."""
        code = id_code(self._codes[detection.dictionary], detection.tag_id)
        return code is not None and bool(np.array_equal(reading.white, code > 0.5))

    def _clear(self, reading: Reading, detection: Detection) -> bool:
        """Whether ``detection`` is seen nearly face on (:data:`CORRECTED_MIN_SIDE_RATIO`)
        and its cells (``reading``) read as its id by :data:`CORRECTED_MARGIN_BITS` against
        every other id of its dictionary."""
        sides = quad_sides(detection.corners)
        if min(sides) < CORRECTED_MIN_SIDE_RATIO * max(sides):
            return False
        codes = self._codes[detection.dictionary]
        if id_code(codes, detection.tag_id) is None:
            return False
        margin = decision_margin(reading.levels(), detection.tag_id, codes)
        return margin >= CORRECTED_MARGIN_BITS


def _whole(shape: tuple[int, ...]) -> bool:
    """Whether a frame of ``shape`` is read whole by a pass (else at its candidates)."""
    return max(shape[:2]) <= MAX_SIDE_PX and min(shape[:2]) <= MID_LINES


def _shrunk(corners: Quad, offset: tuple[int, int]) -> Quad:
    """Corners read on an image enlarged :data:`SCALE` times, in the pixels of the image it
    was enlarged from, shifted by ``offset`` (x, y): the centre of the enlarged pixel (x, y)
    is the original's (x + 0.5) / SCALE - 0.5."""
    shrunk = (corners + np.float32(0.5)) / np.float32(SCALE) - np.float32(0.5)
    return np.asarray(shrunk + np.asarray(offset, np.float32), np.float32)
