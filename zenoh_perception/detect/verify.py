"""Checks that can only veto a marker OpenCV's ArUco detector decided on. Pure: no Zenoh, no
logging.

OpenCV's ``ArucoDetector`` proposes every marker and its id; :class:`Verifier` re-reads each
one from the grey image and may reject it, never add one nor change its id or corners. The
marker is warped onto a grid of its own cells plus one ring of cells outside it (the quiet
zone), each cell read as the mean of its central part. From those cell values:

- ``quiet_zone``: a printed marker sits on a light margin, as light as its white cells; a dark
  key-cap with a light glyph, a book spine or a pictogram on a sign sits on something dark.
  The ring's median level, on the scale from the border's level (0) to the white cells' (1),
  must reach :data:`QUIET_MIN`;
- ``cells``: a marker's cells are either as dark as its border or as light as its white
  cells; a glyph's strokes leave cells half covered. The share of cells midway between the two
  levels must stay under :data:`MIDWAY_MAX`.

Both only look at markers whose mean side is under :data:`SMALL_SIDE_PX`: larger ones are
read by OpenCV from enough pixels that no look-alike on the project's real corpus reached
that size, and a large marker is the one least worth losing. docs/benchmarks.md has the
measured distributions on true and false detections that set the thresholds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.detect.types import Detection

Gray = npt.NDArray[np.uint8]

#: The veto reasons, in the order they are checked.
REASONS: Final = ("quiet_zone", "border", "grid", "cells")
#: Pixels per cell of the warped grid; each cell is read on its central CELL_CORE share.
CELL_PX: Final = 8
CELL_CORE: Final = 0.5
#: Least median level of the quiet zone, from the border's level (0) to the white cells' (1).
QUIET_MIN: Final = 0.35
#: Most border cells nearer the white level than the border's own, as a share.
BORDER_LIGHT_MAX: Final = 0.35
#: Most ratio of the cells' spread on the marker's own grid to the least on another grid size.
GRID_RATIO_MAX: Final = 3.0
#: Most cells (border and inner) midway between the dark and light levels, as a share.
MIDWAY_MAX: Final = 0.5
#: What counts as midway: a level this far from both 0 and 1 on the same scale.
MIDWAY_BAND: Final = 0.25


@dataclass(frozen=True, slots=True)
class Reading:
    """A marker's cells as re-read from the image: levels on the border-to-white scale."""

    side_px: float
    quiet: float  # median level of the quiet zone's cells (those inside the image)
    midway: float  # share of the marker's cells midway between dark and light
    contrast: float  # white cells' level minus the border's, grey levels
    light: float  # white cells' level, grey levels
    spread: float  # mean standard deviation inside the marker's cells, on the same scale
    border_light: float  # share of border cells nearer the white level than the border's
    side_ratio: float  # shortest side over longest
    grid_ratio: float  # spread on its own grid over the least spread on another grid size


def mean_side(corners: npt.NDArray[np.float32]) -> float:
    return float(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1).mean())


def _cells(
    gray: Gray, corners: npt.NDArray[np.float32], marker_cells: int
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """The marker warped onto ``marker_cells`` (border included) cells a side plus one ring of
    cells outside it: each cell's mean and standard deviation over its central part, and
    whether that part lies inside the image."""
    cells = marker_cells + 2
    side = cells * CELL_PX
    lo, hi = CELL_PX, (cells - 1) * CELL_PX
    target = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], np.float32)
    warp = cv2.getPerspectiveTransform(np.asarray(corners, np.float32), target)
    patch = cv2.warpPerspective(gray, warp, (side, side), flags=cv2.INTER_LINEAR)
    margin = round(CELL_PX * (1.0 - CELL_CORE) / 2.0)
    core = slice(margin, CELL_PX - margin)
    blocks = patch.reshape(cells, CELL_PX, cells, CELL_PX)[:, core, :, core].astype(np.float32)
    # each cell's central part, corner to corner, back in the image
    edges = np.arange(cells, dtype=np.float32) * CELL_PX
    ends = np.stack([edges + margin, edges + CELL_PX - margin - 1], axis=1)  # (cells, 2)
    xs, ys = ends[None, :, None, :], ends[:, None, :, None]
    points = np.stack(np.broadcast_arrays(xs, ys), axis=-1).reshape(-1, 1, 2)
    back = cv2.perspectiveTransform(points, np.linalg.inv(warp)).reshape(cells, cells, 4, 2)
    height, width = gray.shape[:2]
    valid = (
        (back[..., 0] >= 0)
        & (back[..., 0] <= width - 1)
        & (back[..., 1] >= 0)
        & (back[..., 1] <= height - 1)
    ).all(axis=2)
    return blocks.mean(axis=(1, 3)), blocks.std(axis=(1, 3)), valid


def _rings(cells: int) -> tuple[npt.NDArray[np.bool_], ...]:
    """Masks of the quiet ring, the border ring and the inner cells of a grid of ``cells``."""
    ring = np.zeros((cells, cells), bool)
    ring[0, :] = ring[-1, :] = ring[:, 0] = ring[:, -1] = True
    border = np.zeros((cells, cells), bool)
    border[1 : cells - 1, 1 : cells - 1] = True
    border[2 : cells - 2, 2 : cells - 2] = False
    inner = np.zeros((cells, cells), bool)
    inner[2 : cells - 2, 2 : cells - 2] = True
    return ring, border, inner


def read_cells(gray: Gray, corners: npt.NDArray[np.float32], marker_size: int) -> Reading:
    """Re-read the marker at ``corners`` (OpenCV's order) with ``marker_size`` inner cells a
    side, as a :class:`Reading`."""
    grid, stds, valid = _cells(gray, corners, marker_size + 2)
    ring, border, inner = _rings(marker_size + 4)
    dark = float(np.median(grid[border]))
    code = grid[inner]
    # white cells: the inner cells above the midpoint between the border and the lightest cell
    split = (dark + float(code.max())) / 2.0
    light = float(np.median(code[code > split])) if (code > split).any() else dark
    contrast = light - dark
    scale = contrast if contrast > 1.0 else 1.0
    levels = (grid - dark) / scale
    quiet_cells = levels[ring & valid]
    quiet = float(np.median(quiet_cells)) if quiet_cells.size else 1.0
    marker = levels[border | inner]
    midway = float(np.mean((marker > MIDWAY_BAND) & (marker < 1.0 - MIDWAY_BAND)))
    spread = float(stds[border | inner].mean()) / scale
    border_light = float(np.mean(levels[border] > 0.5))
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)
    side_ratio = float(sides.min() / max(float(sides.max()), 1e-6))
    # the same quad read as another grid size: a marker's cells are most uniform on its own
    others = []
    for size in (4, 5, 6, 7):
        if size != marker_size:
            _, other_stds, _ = _cells(gray, corners, size + 2)
            _, other_border, other_inner = _rings(size + 4)
            others.append(float(other_stds[other_border | other_inner].mean()) / scale)
    grid_ratio = spread / max(min(others), 1e-6)
    return Reading(
        mean_side(corners),
        quiet,
        midway,
        contrast,
        light,
        spread,
        border_light,
        side_ratio,
        grid_ratio,
    )


def veto_reason(reading: Reading) -> str | None:
    """The first of :data:`REASONS` that rejects ``reading``, or None to keep it."""
    if reading.quiet < QUIET_MIN:
        return "quiet_zone"
    if reading.border_light > BORDER_LIGHT_MAX:
        return "border"
    if reading.grid_ratio > GRID_RATIO_MAX:
        return "grid"
    if reading.midway > MIDWAY_MAX:
        return "cells"
    return None


class Verifier:
    """Vetoes detections of ``dictionary``'s markers that the checks above reject."""

    def __init__(self, dictionary: str) -> None:
        self._marker_size = int(aruco_dictionary(dictionary).markerSize)

    def check(self, gray: Gray, detection: Detection) -> str | None:
        """Why ``detection`` is vetoed, or None when it is kept."""
        return veto_reason(read_cells(gray, detection.corners, self._marker_size))

    def verify(self, gray: Gray, detections: list[Detection]) -> tuple[list[Detection], list[str]]:
        """The detections kept (same objects, same order) and the reason of each veto."""
        kept: list[Detection] = []
        reasons: list[str] = []
        for detection in detections:
            reason = self.check(gray, detection)
            if reason is None:
                kept.append(detection)
            else:
                reasons.append(reason)
        return kept, reasons
