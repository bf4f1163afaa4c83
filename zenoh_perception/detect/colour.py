"""Colour check: ArUco tags are printed black on white, so they have no colour of their own.

Pure numpy + OpenCV. The detectors work on grey, where a bright pictogram on a dark box (a
yellow warning sign, a green exit sign, a cyan packaging icon) can read as a valid code and fit
the ideal marker about as well as a real far tag does when its cells are 2-4 px. In colour
they differ: between the white and the black cells of a print the difference is the same in
every channel (whatever the light's brightness), while a coloured pictogram differs by much
more in one channel than in another.

:func:`chroma_many` measures, for each detection, the white-minus-black difference per channel
(the means over the marker's own white and black cells, sampled at the cell centres through
the homography of its corners) and returns ``(max - min) / mean`` over the channels: about 0
for a print under white light, 0.35 and more for the coloured look-alikes of the bench. On the
bench's generated frames (three seeds, every resolution and the drive), real tags measure at
most 0.11 (99.9 % under 0.05) and coloured look-alikes at least 0.35; white pictograms are not
caught (they are as achromatic as a tag). A camera without white balance, or tags under
strongly coloured light, shift every tag's chroma alike: raise the limit or disable the check.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.refine import MarkerModel
from zenoh_perception.detection import Detection

Image = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float64]  # (4, 2) corners

#: Default largest chroma of a real (black on white) tag; see the module doc.
DEFAULT_MAX_CHROMA: Final = 0.2
_MIN_DIFFERENCE: Final = 1.0  # grey levels; guards the division on a flat patch


class ChromaCheck:
    """Chroma of detections of one ArUco dictionary (see the module doc)."""

    def __init__(self, dictionary: Any, model: MarkerModel | None = None) -> None:
        # cell centres, homographies, black cells (a detector passes the model it has)
        self._model = model if model is not None else MarkerModel(dictionary)

    def chroma_many(self, image: Image, detections: Sequence[Detection]) -> list[float]:
        """Chroma of each detection in ``image`` (H, W, 3 or 4 channels; a 4th is ignored)."""
        return self.chroma_of(
            image, [(det.tag_id, np.asarray(det.corners, dtype=np.float64)) for det in detections]
        )

    def chroma_of(self, image: Image, candidates: Sequence[tuple[int, Quad]]) -> list[float]:
        """Chroma of each (id, corners) in ``image``: :meth:`chroma_many` of candidates that
        are not detections yet (a detector checks them before its costlier checks)."""
        if image.ndim != 3 or image.shape[2] < 3:
            msg = f"expected a colour image (H, W, 3 or 4), got shape {image.shape}"
            raise ValueError(msg)
        if not candidates:
            return []
        values = self._model.cell_samples(image, [quad for _, quad in candidates])
        black = np.array([self._model.black_cells(tag_id) for tag_id, _ in candidates], float)
        white = 1.0 - black
        # per candidate and channel: mean over its white cells - mean over its black cells
        sums = np.matmul(np.stack([white, black], axis=1), values[:, :, :3])  # (n, 2, 3)
        counts = np.stack([white.sum(axis=1), black.sum(axis=1)], axis=1)[:, :, None]
        means = sums / counts
        difference = means[:, 0] - means[:, 1]  # (n, 3)
        scale = np.maximum(difference.mean(axis=1), _MIN_DIFFERENCE)
        chroma = (difference.max(axis=1) - difference.min(axis=1)) / scale
        out: list[float] = chroma.tolist()
        return out

    def keep(
        self, image: Image, detections: Sequence[Detection], max_chroma: float
    ) -> list[Detection]:
        """The detections whose chroma is at most ``max_chroma``."""
        chroma = self.chroma_many(image, detections)
        return [d for d, c in zip(detections, chroma, strict=True) if c <= max_chroma]
