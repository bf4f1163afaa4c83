"""Vetoes a marker OpenCV's ArUco detector decided on, never adds one. Pure: no Zenoh, no
logging.

OpenCV's ``ArucoDetector`` proposes every marker and its id; :class:`Verifier` re-reads each
one from the grey image (:mod:`.cells`) and may reject it by the rules of :mod:`.rules`, never
add one nor change its id or corners. :func:`measure` reads every rule's number whatever the
thresholds, for tools/thresholds.py.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.cells import (
    Bits,
    Reading,
    decision_margin,
    dictionary_codes,
    id_code,
    min_distance,
    quad_sides,
    read_cells,
    stroke_excess,
)
from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.detect.regions import seen_again
from zenoh_perception.detect.rules import DEFAULTS, Measures, vetoes
from zenoh_perception.detect.types import Detection, dictionary_names

Gray = npt.NDArray[np.uint8]


class Verifier:
    """Vetoes detections of ``dictionary``'s markers (one dictionary, or several separated by
    commas) that the checks above reject; a detection is read on the grid of the dictionary
    it names.

    :meth:`verify` is meant for the frames of one stream in order: a detection that is one
    kept on the frame before seen again (:func:`~.regions.seen_again`) is kept without being
    read again.
    """

    def __init__(self, dictionary: str) -> None:
        names = dictionary_names(dictionary)
        self._sizes = {name: int(aruco_dictionary(name).markerSize) for name in names}
        # ids one bit apart (ARUCO_ORIGINAL) leave a true tag no margin once it is blurred
        self._codes = {name: dictionary_codes(name) for name in names if min_distance(name) > 1}
        self._all_codes = {name: dictionary_codes(name) for name in names}
        self._first = names[0]
        self._shape: tuple[int, ...] = ()
        self._kept: list[Detection] = []

    def check(self, gray: Gray, detection: Detection) -> str | None:
        """Why ``detection`` is vetoed (the first of :func:`vetoes`), or None when it is kept.
        Each measure is read only when a rule asks for it."""
        name = detection.dictionary if detection.dictionary in self._sizes else self._first
        measured = _Measuring(
            gray, detection, self._sizes[name], self._all_codes[name], self._codes.get(name)
        )
        return next(vetoes(measured, DEFAULTS), None)

    def verify(self, gray: Gray, detections: list[Detection]) -> tuple[list[Detection], list[str]]:
        """The detections kept (the same objects, in order) and the reason of each veto."""
        self.start(gray)
        kept: list[Detection] = []
        reasons: list[str] = []
        for detection in detections:
            reason = self.judge(gray, detection)
            if reason is None:
                kept.append(detection)
            else:
                reasons.append(reason)
        self.commit(kept)
        return kept, reasons

    # :meth:`verify` in steps, for a caller that decides on some detections before others:
    # start, judge each detection of the frame once (in any order), commit those kept.

    def start(self, gray: Gray) -> None:
        """A frame of the stream begins (one of another size begins the stream anew)."""
        if gray.shape != self._shape:
            self._shape, self._kept = gray.shape, []

    def judge(self, gray: Gray, detection: Detection) -> str | None:
        """:meth:`check`, unless ``detection`` is one kept on the frame before seen again."""
        if any(seen_again(detection, before) for before in self._kept):
            return None
        return self.check(gray, detection)

    def commit(self, kept: list[Detection]) -> None:
        """The frame's detections kept, for the next frame's :meth:`judge`."""
        self._kept = kept


def read_detection(
    gray: Gray, detection: Detection, dictionary: str, *, local_always: bool = False
) -> Reading:
    """:func:`read_cells` for ``detection`` on the grid of ``dictionary`` (one predefined
    dictionary), its white cells those of the id OpenCV read."""
    size = int(aruco_dictionary(dictionary).markerSize)
    bits = id_code(dictionary_codes(dictionary), detection.tag_id)
    side_px = sum(quad_sides(detection.corners)) / 4
    return read_cells(gray, detection.corners, size, side_px, bits, local_always=local_always)


def measure(gray: Gray, detection: Detection, dictionary: str) -> Measures:
    """What every rule of :func:`vetoes` measures on ``detection`` (read on the grid of
    ``dictionary``, one predefined dictionary), all of it, whatever the thresholds."""
    size = int(aruco_dictionary(dictionary).markerSize)
    every = dictionary_codes(dictionary)
    codes = every if min_distance(dictionary) > 1 else None
    m = _Measuring(gray, detection, size, every, codes, local_always=True)
    return Measures(
        shortest_side_px=m.shortest_side_px,
        cells_across=m.cells_across,
        quiet=m.quiet,
        quiet_local=m.quiet_local,
        border_light=m.border_light,
        grid_ratio=m.grid_ratio,
        strokes=m.strokes,
        margin=m.margin,
    )


class _Measuring:
    """The measures of one detection, each read the first time a rule asks for it: the quad's
    sides at once, the cells (:func:`read_cells`) for the first rule past ``resolution``, the
    seams and the code's margin only for their rules. ``codes``: the dictionary's codes where
    the margin rule applies (None: it does not); ``every``: all of them (the white cells)."""

    def __init__(
        self,
        gray: Gray,
        detection: Detection,
        marker_size: int,
        every: Bits,
        codes: Bits | None,
        *,
        local_always: bool = False,
    ) -> None:
        self._gray = gray
        self._detection = detection
        self._size = marker_size
        self._every = every
        self._codes = codes
        self._local_always = local_always
        self._sides = quad_sides(detection.corners)
        self.shortest_side_px = min(self._sides)
        self.cells_across = marker_size + 2

    @cached_property
    def reading(self) -> Reading:
        bits = id_code(self._every, self._detection.tag_id)
        side_px = sum(self._sides) / 4
        return read_cells(
            self._gray,
            self._detection.corners,
            self._size,
            side_px,
            bits,
            local_always=self._local_always,
        )

    @property
    def quiet(self) -> float:
        return self.reading.quiet

    @property
    def quiet_local(self) -> float:
        local = self.reading.quiet_local
        assert local is not None  # read whenever quiet is below QUIET_MIN, or local_always
        return local

    @property
    def border_light(self) -> float:
        return self.reading.border_light

    @property
    def grid_ratio(self) -> float:
        return self.reading.grid_ratio

    @cached_property
    def strokes(self) -> float:
        return stroke_excess(self.reading)

    @cached_property
    def margin(self) -> float | None:
        codes, tag_id = self._codes, self._detection.tag_id
        if codes is None or id_code(codes, tag_id) is None:
            return None  # no margin rule for this dictionary, or not one of its ids
        return decision_margin(self.reading.levels(), tag_id, codes)
