"""What the demo's rover passes besides its tags: the things real cameras meet that OpenCV's
default detector reads ids on (pure: numpy + cv2).

Each drive shows, in the lower part of the frame, one kind of the real corpus's negatives
(:data:`KINDS`: a keyboard, book spines, a tiled wall, other families' markers), drawn by
:func:`~zenoh_perception_bench.scene.lookalikes.lookalike_frame`, with the tags standing in front
of it: the layer is left out around every tag in view (its quiet zone included), so a tag
reads as it would on its post.

The synthetic adversaries of the scene generator (an exact valid code hidden in a blob, a
glyph or a bare code, which no real camera meets) are the demo's ``--adversaries`` instead.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene import MarkerTruth
from zenoh_perception_bench.scene.lookalikes import lookalike_frame

Image = npt.NDArray[np.uint8]

#: The kinds drawn, one per drive in turn: the corpus's keyboards, text, tiles and markers of
#: other families. Handling pictograms are not among them: the veto removes about 98 in 100
#: of the ids OpenCV reads on small blurred ones, not all.
KINDS: Final = ("keys", "text", "tiles", "other_family")
#: Share of the frame's height the layer covers, from the bottom.
BAND: Final = 0.4
#: Margin kept clear around a tag, in tag sides (its quiet zone and a little more).
CLEAR_SIDES: Final = 0.5


def layer(kind: str, dictionary: str, width: int, height: int, seed: int) -> Image:
    """The BGRA layer of ``kind`` for a ``width`` x ``height`` frame (its lower band)."""
    rows = max(1, round(height * BAND))
    return lookalike_frame(kind, dictionary, np.random.default_rng(seed), width, rows)


def layers(dictionary: str, width: int, height: int, seed: int = 0) -> tuple[Image, ...]:
    """One layer of each of :data:`KINDS`, in order (drawn once: up to a second each at
    HD720, too long to draw between two frames)."""
    return tuple(layer(kind, dictionary, width, height, seed) for kind in KINDS)


def composed(image: Image, band: Image, markers: Sequence[MarkerTruth]) -> Image:
    """``image`` with ``band`` over its lower rows, but for the tags in view and their margin."""
    height = image.shape[0]
    top = height - band.shape[0]
    keep = np.zeros(band.shape[:2], np.uint8)  # where the scene stays: the tags
    for marker in markers:  # those partly in view too: their visible part stays clear
        centre = marker.corners.mean(axis=0)
        grown = centre + (marker.corners - centre) * (1.0 + 2.0 * CLEAR_SIDES)
        quad = np.round(grown - (0.0, top)).astype(np.int32)
        cv2.fillConvexPoly(keep, quad, 1)
    out = image.copy()
    lower = out[top:]
    np.copyto(lower, band, where=(keep == 0)[:, :, None])
    return out
