"""Colour check: ArUco tags are printed black on white, so they have no colour of their own.

Pure numpy + OpenCV. The detectors work on grey, where a bright pictogram on a dark box (a
yellow warning sign, a green exit sign, a white icon on a dark blue plate) can read as a valid
code and fit the ideal marker about as well as a real far tag does when its cells are 2-4 px.
In colour they differ. :meth:`ChromaCheck.measure` takes two measures of each candidate from
its cell centres (sampled through the homography of its corners):

Chroma of the contrast (``chroma``)
    The white-minus-black difference per channel (means over the marker's own white and black
    cells), ``(max - min) / mean`` over the channels: the same in every channel for a print
    under white light, whatever its brightness, so about 0; 0.35 and more for the coloured
    look-alikes of the bench. Real tags of the bench's generated frames (three seeds, every
    resolution and the drive) measure at most 0.11, 99.9 % under 0.05. A white pictogram is as
    achromatic as a tag by this measure.

Tint of the black (``black_tint``, ``black_tint_z``)
    Black ink reflects a few percent of the light, so a tag's black cells have the colour of
    the light, as its white cells do, dimmed, plus the camera's black level, which is grey: the
    black's chroma (its deviation from grey) lies between none and the white's own, scaled by
    the black's brightness over the white's. ``black_tint`` is the black cells' mean chroma
    beyond that range, in grey levels (largest channel); ``black_tint_z`` is the same over its
    standard error, from the scatter of the black cells (so sensor noise alone does not make a
    tag fail). A white pictogram on a dark box, or a dark window with bright reflections,
    has a dark of its own colour: a dark blue, green or brown plate. A candidate fails when
    both are large (``max_black_tint``, :data:`MIN_BLACK_TINT_Z`).

    On the bench's generated frames (twelve seeds: 17,674 real tags, and 57 white look-alikes
    that passed every other check) real tags measured at most 1.94 grey levels and 4.5
    standard errors; 31 of the 57 look-alikes measured more than 2 levels and 5 errors.

A camera without white balance, or tags under strongly coloured light, shift every tag's
chroma alike: raise the limits or turn the checks off (:class:`ColourLimits`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.refine import MarkerModel
from zenoh_perception.detection import Detection

Image = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float64]  # (4, 2) corners

#: Default largest chroma of a real (black on white) tag; see the module doc.
DEFAULT_MAX_CHROMA: Final = 0.2
#: Default largest tint of a tag's black, grey levels (an 8-bit camera's black level and
#: rounding stay below it); see the module doc.
DEFAULT_MAX_BLACK_TINT: Final = 2.0
#: A black tint fails only when it is also this many standard errors (sensor noise alone stays
#: below it).
MIN_BLACK_TINT_Z: Final = 5.0
_MIN_DIFFERENCE: Final = 1.0  # grey levels; guards the divisions on a flat patch
_MIN_ERROR: Final = 0.1  # grey levels; the standard error of a noise-free (drawn) marker
_TO_CHROMA: Final = np.eye(3) - 1.0 / 3.0  # colour @ this = its deviation from grey


@dataclass(frozen=True, slots=True)
class ColourLimits:
    """What a black-on-white print may measure (see the module doc); 0 turns a check off."""

    max_chroma: float = DEFAULT_MAX_CHROMA
    max_black_tint: float = DEFAULT_MAX_BLACK_TINT

    @property
    def active(self) -> bool:
        """Whether any check is on."""
        return self.max_chroma > 0.0 or self.max_black_tint > 0.0


#: Both checks off.
NO_COLOUR_CHECK: Final = ColourLimits(0.0, 0.0)


@dataclass(frozen=True, slots=True)
class ColourMeasure:
    """The colour of one candidate tag (see the module doc)."""

    chroma: float
    black_tint: float
    black_tint_z: float

    def achromatic(self, limits: ColourLimits) -> bool:
        """Whether a black-on-white print may look like this, within ``limits``."""
        if 0.0 < limits.max_chroma < self.chroma:
            return False
        tinted = 0.0 < limits.max_black_tint < self.black_tint
        return not (tinted and self.black_tint_z >= MIN_BLACK_TINT_Z)


class ChromaCheck:
    """Colour measures of detections of one ArUco dictionary (see the module doc)."""

    def __init__(self, dictionary: Any, model: MarkerModel | None = None) -> None:
        # cell centres, homographies, black cells (a detector passes the model it has)
        self._model = model if model is not None else MarkerModel(dictionary)

    def measure(self, image: Image, detections: Sequence[Detection]) -> list[ColourMeasure]:
        """The colour of each detection in ``image`` (H, W, 3 or 4 channels; a 4th is
        ignored)."""
        return self.measure_candidates(
            image, [(det.tag_id, np.asarray(det.corners, dtype=np.float64)) for det in detections]
        )

    def measure_candidates(
        self, image: Image, candidates: Sequence[tuple[int, Quad]]
    ) -> list[ColourMeasure]:
        """:meth:`measure` of (id, corners) candidates that are not detections yet (a
        detector checks them before its costlier checks)."""
        if image.ndim != 3 or image.shape[2] < 3:
            msg = f"expected a colour image (H, W, 3 or 4), got shape {image.shape}"
            raise ValueError(msg)
        if not candidates:
            return []
        values = self._model.cell_samples(image, [quad for _, quad in candidates])[:, :, :3]
        black = np.array([self._model.black_cells(tag_id) for tag_id, _ in candidates], float)
        # chroma of each cell: its deviation from grey
        chroma = np.matmul(values, _TO_CHROMA)
        # per candidate, over its white and over its black cells: the sums of each channel,
        # and of each channel's chroma squared (one product; the rest on a few floats each:
        # numpy's fixed cost per call would dwarf the arithmetic)
        masks = np.stack([1.0 - black, black], axis=1)  # (n, 2, cells)
        sums = np.matmul(masks, np.concatenate([values, chroma * chroma], axis=2))
        counts = masks.sum(axis=2)
        return [
            _measure(white[:3], black_sums[:3], black_sums[3:], n_white, n_black)
            for (white, black_sums), (n_white, n_black) in zip(
                sums.tolist(), counts.tolist(), strict=True
            )
        ]

    def keep(
        self, image: Image, detections: Sequence[Detection], limits: ColourLimits
    ) -> list[Detection]:
        """The detections that may be black-on-white prints (:meth:`ColourMeasure.achromatic`)."""
        measures = self.measure(image, detections)
        return [d for d, m in zip(detections, measures, strict=True) if m.achromatic(limits)]


def _measure(
    white_sums: list[float],
    black_sums: list[float],
    black_squares: list[float],
    n_white: float,
    n_black: float,
) -> ColourMeasure:
    """The measures of one candidate (module doc) from the per-channel sums over its white
    and black cells, and the sums over its black cells of each channel's chroma squared.
    (Three channels spelled out: list comprehensions would cost more than the arithmetic.)"""
    w0, w1, w2 = (v / n_white for v in white_sums)
    b0, b1, b2 = (v / n_black for v in black_sums)
    d0, d1, d2 = w0 - b0, w1 - b1, w2 - b2
    scale = max((d0 + d1 + d2) / 3.0, _MIN_DIFFERENCE)
    chroma = (max(d0, d1, d2) - min(d0, d1, d2)) / scale
    # the chroma the black may have: from none to the white's, dimmed to the black's level
    white_level, black_level = (w0 + w1 + w2) / 3.0, (b0 + b1 + b2) / 3.0
    dim = black_level / max(white_level, _MIN_DIFFERENCE)
    a0, a1, a2 = (w0 - white_level) * dim, (w1 - white_level) * dim, (w2 - white_level) * dim
    c0, c1, c2 = b0 - black_level, b1 - black_level, b2 - black_level
    reach = a0 * a0 + a1 * a1 + a2 * a2
    share = (c0 * a0 + c1 * a1 + c2 * a2) / reach if reach > 0.0 else 0.0
    share = min(max(share, 0.0), 1.0)
    excess = [abs(c0 - share * a0), abs(c1 - share * a1), abs(c2 - share * a2)]
    # the channel furthest off, and the standard error of its mean from the cells' scatter
    channel = excess.index(max(excess))
    mean = (c0, c1, c2)[channel]
    scatter = max(black_squares[channel] - n_black * mean * mean, 0.0) / max(n_black - 1.0, 1.0)
    error = max(math.sqrt(scatter / n_black), _MIN_ERROR)
    return ColourMeasure(chroma, excess[channel], excess[channel] / error)
