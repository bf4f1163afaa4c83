"""A stream's markers reported only once seen on consecutive frames. Pure: no Zenoh, no
logging.

A look-alike that OpenCV reads on one frame only (glare on a screen, a glyph passing by) is a
false id a single frame long, while a printed marker in view stays: :class:`Confirmer` holds a
detection back until the same marker was found on ``frames`` consecutive frames: the same id
and dictionary, within :data:`PLACE` sides of where it was and :data:`SIZE` of its size (a
hand-held camera or a sparse image sequence moves a marker by more than a side between
frames). It only drops detections, never adds one or changes it; the price is a
new marker's first ``frames - 1`` frames. ``frames = 1`` reports everything at once.
"""

from __future__ import annotations

from typing import Final

from zenoh_perception.detect.regions import seen_again
from zenoh_perception.detect.types import Detection

#: How far (mean sides) a marker may move, and by what share its size may change, between two
#: frames and still be the marker seen before.
PLACE: Final = 2.0
SIZE: Final = 0.5


class Confirmer:
    """Holds back each marker of one stream until seen on ``frames`` frames in a row."""

    def __init__(self, frames: int) -> None:
        if frames < 1:
            msg = f"frames must be at least 1, not {frames}"
            raise ValueError(msg)
        self.frames = frames
        self._shape: tuple[int, ...] = ()
        self._seen: list[tuple[Detection, int]] = []

    def confirm(
        self, shape: tuple[int, ...], detections: list[Detection]
    ) -> tuple[list[Detection], int]:
        """The detections of a frame of ``shape`` that are confirmed (the same objects, in
        order), and how many were held back."""
        if shape != self._shape:  # another stream's size: nothing carries over
            self._shape, self._seen = shape, []
        seen: list[tuple[Detection, int]] = []
        kept: list[Detection] = []
        for detection in detections:
            before = (
                count for known, count in self._seen if seen_again(detection, known, PLACE, SIZE)
            )
            count = 1 + max(before, default=0)
            seen.append((detection, count))
            if count >= self.frames:
                kept.append(detection)
        self._seen = seen
        return kept, len(detections) - len(kept)
