"""Checks that can only veto a marker OpenCV's ArUco detector decided on. Pure: no Zenoh, no
logging.

OpenCV's ``ArucoDetector`` proposes every marker and its id; :class:`Verifier` re-reads each
one from the grey image and may reject it, never add one nor change its id or corners. The
marker's quad is warped onto a grid of its own cells (border included) plus one ring of cells
outside it (the quiet zone), each cell read on its central part. On the scale from the
border's median level (0) to the white cells' (1):

- ``resolution``: a quad whose shortest side holds less than :data:`MIN_PX_PER_CELL` pixel
  per cell across it (the inner cells and the border, e.g. 6 for DICT_4X4) was decoded below
  the image's own resolution (slivers one or two pixels wide on fur or window frames; a true
  tag, however oblique, keeps more than one pixel a cell on the real corpus, and down to
  0.875 on the generator's oblique 10 px tags). Checked before the cells are read;
- ``quiet_zone``: a printed marker sits on a light margin as light as its white cells (the
  same paper). The ring's median must lie in [:data:`QUIET_MIN`, :data:`QUIET_MAX`]: below,
  the "marker" is a dark patch on something dark (a key-cap with a light glyph on a dark
  keyboard, a letter on a book spine); above, its "white" cells are far darker than what
  surrounds it (a dark window or a faint glyph in a light scene). Ring cells outside the image
  are left out: a marker at the image border keeps its chance;
- ``border``: a marker's border is dark all round. At most :data:`BORDER_LIGHT_MAX` of its
  border cells may be nearer the white level than the border's;
- ``grid``: the quad read on the grids of the families with more cells (up to 7 inner cells
  a side): a marker's cells are more uniform on its own grid than on a finer one, so when the
  cells' spread (mean standard deviation inside each cell) on its own grid is more than
  :data:`GRID_RATIO_MAX` times the least on a finer grid, the quad is a finer family's marker
  whose cells happen to read as a code of the coarser one (tag36h11 read as DICT_4X4 or
  tag16h5, 6X6 read as DICT_4X4 or 5X5: the confusions the real corpus shows).

docs/benchmarks.md gives the distributions of these features on the true and false
detections of the project's real corpus that set the thresholds, and what each rule removes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.detect.types import Detection, dictionary_names
from zenoh_perception.tags.geometry import mean_side

Gray = npt.NDArray[np.uint8]
Mask = npt.NDArray[np.bool_]

#: The veto reasons, in the order they are checked.
REASONS: Final = ("resolution", "quiet_zone", "border", "grid")
#: Fewest pixels per cell along a quad's shortest side (cells: inner cells and border).
MIN_PX_PER_CELL: Final = 0.5
#: Pixels per cell of the warped grid; each cell is read on its central half (4 x 4 pixels).
CELL_PX: Final = 8
_CORE: Final = slice(2, 6)
_CORE_PX: Final = 4
#: The quiet zone's median level must lie in [QUIET_MIN, QUIET_MAX] (border 0, white cells 1).
QUIET_MIN: Final = 0.35
QUIET_MAX: Final = 1.8
#: Most share of border cells nearer the white level than the border's.
BORDER_LIGHT_MAX: Final = 0.35
#: Most ratio of the cells' spread on the marker's own grid to the least on a finer grid.
GRID_RATIO_MAX: Final = 2.5
#: Inner cells a side of the families' grids (DICT_4X4 and tag16h5 ... DICT_7X7).
GRID_SIZES: Final = (4, 5, 6, 7)


@dataclass(frozen=True, slots=True)
class Reading:
    """A marker's cells as re-read from the image (levels: border 0, white cells 1)."""

    side_px: float  # mean side of the quad, pixels
    quiet: float  # median level of the quiet zone's cells inside the image
    contrast: float  # white cells' level minus the border's, grey levels
    border_light: float  # share of border cells nearer the white level than the border's
    grid_ratio: float  # cells' spread on its own grid over the least on a finer grid


def shortest_side(corners: npt.NDArray[np.float32]) -> float:
    """Shortest side of a quad, pixels."""
    return float(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1).min())


@cache
def _layout(marker_size: int) -> tuple[Mask, Mask, Mask, npt.NDArray[np.float32]]:
    """For ``marker_size`` inner cells a side: the masks of the quiet ring, the border and the
    inner cells of the warped grid, and the warped grid's quad corners."""
    cells = marker_size + 4
    ring = np.zeros((cells, cells), bool)
    ring[0, :] = ring[-1, :] = ring[:, 0] = ring[:, -1] = True
    inner = np.zeros((cells, cells), bool)
    inner[2:-2, 2:-2] = True
    border = ~ring & ~inner
    lo, hi = CELL_PX, (cells - 1) * CELL_PX
    target = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], np.float32)
    return ring, border, inner, target


def _warp(
    gray: Gray, corners: npt.NDArray[np.float32], marker_size: int
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float64]]:
    """Each cell's mean and standard deviation over its central part (two (cells, cells)
    arrays), and the homography used."""
    cells = marker_size + 4
    target = _layout(marker_size)[3]
    warp = cv2.getPerspectiveTransform(np.asarray(corners, np.float32), target)
    patch = cv2.warpPerspective(gray, warp, (cells * CELL_PX, cells * CELL_PX))
    core = patch.reshape(cells, CELL_PX, cells, CELL_PX)[:, _CORE, :, _CORE]
    values = core.reshape(cells * _CORE_PX, cells * _CORE_PX).astype(np.float32)
    # a 4 x 4 block's mean is one pixel of the area-resized image
    mean = cv2.resize(values, (cells, cells), interpolation=cv2.INTER_AREA)
    square = cv2.resize(values * values, (cells, cells), interpolation=cv2.INTER_AREA)
    spread = np.sqrt(np.maximum(square - mean * mean, 0.0))
    return np.asarray(mean, np.float32), np.asarray(spread, np.float32), np.asarray(warp)


def _median(values: npt.NDArray[np.float32]) -> float:
    ordered = np.sort(values, axis=None)
    middle = ordered.size // 2
    return float(
        ordered[middle] if ordered.size % 2 else (ordered[middle - 1] + ordered[middle]) / 2
    )


def _inside(gray: Gray, warp: npt.NDArray[np.float64], marker_size: int) -> Mask:
    """Which cells of the warped grid have their central part inside the image."""
    cells = marker_size + 4
    height, width = gray.shape[:2]
    outline = cv2.perspectiveTransform(
        np.array(
            [
                [[0, 0]],
                [[cells * CELL_PX - 1, 0]],
                [[cells * CELL_PX - 1] * 2],
                [[0, cells * CELL_PX - 1]],
            ],
            np.float32,
        ),
        np.linalg.inv(warp),
    )
    if (
        (outline >= 0).all()
        and (outline[..., 0] <= width - 1).all()
        and (outline[..., 1] <= height - 1).all()
    ):
        return np.ones((cells, cells), bool)  # the whole grid is inside the image
    ends = np.arange(cells, dtype=np.float32)[:, None] * CELL_PX + np.array([2, 5], np.float32)
    xs, ys = np.meshgrid(ends.reshape(-1), ends.reshape(-1))
    points = np.stack([xs, ys], axis=-1).reshape(-1, 1, 2)
    back = cv2.perspectiveTransform(points, np.linalg.inv(warp)).reshape(cells, 2, cells, 2, 2)
    ok = (back >= 0).all(axis=-1) & (back[..., 0] <= width - 1) & (back[..., 1] <= height - 1)
    return np.asarray(ok.all(axis=(1, 3)), bool)


def read_cells(gray: Gray, corners: npt.NDArray[np.float32], marker_size: int) -> Reading:
    """Re-read the marker at ``corners`` (OpenCV's order) with ``marker_size`` inner cells a
    side, as a :class:`Reading`."""
    ring, border, inner, _ = _layout(marker_size)
    grid, spread, warp = _warp(gray, corners, marker_size)
    dark = _median(grid[border])
    code = grid[inner]
    # white cells: the inner cells above the midpoint between the border and the lightest cell
    split = (dark + float(code.max())) / 2.0
    light = _median(code[code > split]) if (code > split).any() else dark
    contrast = light - dark
    scale = max(contrast, 1.0)
    levels = (grid - dark) / scale
    quiet_cells = levels[ring & _inside(gray, warp, marker_size)]
    quiet = _median(quiet_cells) if quiet_cells.size else 1.0
    border_light = float(np.mean(levels[border] > 0.5))
    own = float(spread[~ring].mean())
    least = (
        min(
            float(_warp(gray, corners, size)[1][~_layout(size)[0]].mean())
            for size in GRID_SIZES
            if size > marker_size
        )
        if marker_size < GRID_SIZES[-1]
        else own
    )
    grid_ratio = own / max(least, 1e-3)
    return Reading(mean_side(corners), quiet, contrast, border_light, grid_ratio)


def veto_reason(reading: Reading) -> str | None:
    """The first of :data:`REASONS` that rejects ``reading``, or None to keep it."""
    if not QUIET_MIN <= reading.quiet <= QUIET_MAX:
        return "quiet_zone"
    if reading.border_light > BORDER_LIGHT_MAX:
        return "border"
    if reading.grid_ratio > GRID_RATIO_MAX:
        return "grid"
    return None


class Verifier:
    """Vetoes detections of ``dictionary``'s markers (one dictionary, or several separated by
    commas) that the checks above reject; a detection is read on the grid of the dictionary
    it names."""

    def __init__(self, dictionary: str) -> None:
        names = dictionary_names(dictionary)
        self._sizes = {name: int(aruco_dictionary(name).markerSize) for name in names}
        self._marker_size = self._sizes[names[0]]

    def check(self, gray: Gray, detection: Detection) -> str | None:
        """Why ``detection`` is vetoed, or None when it is kept."""
        size = self._sizes.get(detection.dictionary, self._marker_size)
        if shortest_side(detection.corners) < MIN_PX_PER_CELL * (size + 2):
            return "resolution"
        return veto_reason(read_cells(gray, detection.corners, size))

    def verify(self, gray: Gray, detections: list[Detection]) -> tuple[list[Detection], list[str]]:
        """The detections kept (the same objects, in order) and the reason of each veto."""
        kept: list[Detection] = []
        reasons: list[str] = []
        for detection in detections:
            reason = self.check(gray, detection)
            if reason is None:
                kept.append(detection)
            else:
                reasons.append(reason)
        return kept, reasons
