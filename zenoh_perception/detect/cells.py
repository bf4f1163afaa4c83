"""A marker's cells re-read from the grey image, and the numbers the veto rules
(:mod:`.rules`) compare with their thresholds: the quiet zone, the border, the grids, the
seams between cells (:func:`stroke_excess`) and the code's decision margin
(:func:`decision_margin`). Pure: no Zenoh, no logging.

The marker's quad is warped once onto a grid of its own cells (border included) plus one ring
of cells outside it (the quiet zone); every grid is read from that one patch, each cell on its
central half, on the scale from the border's median level (0) to the white cells' (1).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache, lru_cache
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.detect.rules import QUIET_MIN

Gray = npt.NDArray[np.uint8]
Mask = npt.NDArray[np.bool_]
Floats = npt.NDArray[np.float64]
Matrix = Sequence[Sequence[float]]  # a 3 x 3 matrix, row by row
Bits = npt.NDArray[np.float32]

#: Inner cells a side of the families' grids (DICT_4X4 and tag16h5 ... DICT_7X7).
GRID_SIZES: Final = (4, 5, 6, 7)
#: Pixels a cell of the finest grid gets in the warped patch (its central half: 4 x 4).
FINEST_CELL_PX: Final = 8
#: The local quiet level: how far (Chebyshev distance, cells) from a ring cell the border cells
#: and the white inner cells it is judged against may lie. LOCAL_CONTRAST_MIN: the least
#: difference, grey levels, between a white and a dark reference for a local level to count
#: (fainter, the whole marker's scale is used): a faint pattern on a plain floor (13 px, 13
#: grey levels of contrast, read as DICT_4X4_1000) reads as a clean code on the scale of its
#: own neighbours; any bound from 8 to 32 keeps every figure of the module doc.
LOCAL_BORDER_REACH: Final = 1
LOCAL_WHITE_REACH: Final = 3
LOCAL_CONTRAST_MIN: Final = 16.0
#: How far (Chebyshev distance, cells) from an inner cell the white cells that set its local
#: white level lie (its dark level: the dark cells next to it).
LEVEL_WHITE_REACH: Final = 2


@dataclass(frozen=True, slots=True)
class Reading:
    """A marker's cells as re-read from the image (levels: border 0, white cells 1)."""

    side_px: float  # mean side of the quad, pixels
    quiet: float  # median level of the quiet zone's cells inside the image
    # the same with each ring cell on the scale of the marker cells beside it (_local_quiet),
    # read only when ``quiet`` is below QUIET_MIN (None otherwise; read_cells' local_always
    # reads it anyway): no rule looks at it then
    quiet_local: float | None
    contrast: float  # white cells' level minus the border's, grey levels
    border_light: float  # share of border cells nearer the white level than the border's
    grid_ratio: float  # cells' spread on its own grid over the least on a finer grid
    marker_size: int  # inner cells a side
    cells: Floats  # mean of every cell of the own grid (ring, border, inner), row by row
    white: Mask  # which inner cells are white, row by row
    dark: float  # the border's median, grey levels
    means: Floats  # the mean of every window read (:class:`_Layout`), ``cells`` first
    code: _Code  # what the white cells fix of the rest

    def levels(self) -> npt.NDArray[np.float32]:
        """The inner cells' levels, each on the scale of the cells around it
        (:func:`_local_levels`), clipped to [0, 1], row by row."""
        layout = _layout(self.marker_size)
        code = self.cells[layout.inner_cells]
        fallback = (code - self.dark) / max(self.contrast, 1.0)
        levels = _local_levels(self.cells, code, self.code, fallback, layout)
        return np.minimum(np.maximum(levels, 0.0, out=levels), 1.0, out=levels).astype(np.float32)


def quad_sides(corners: npt.NDArray[np.float32]) -> list[float]:
    """A quad's four sides, pixels, from the first corner to the second on."""
    first, second, third, fourth = corners.reshape(4, 2).tolist()
    return [
        math.dist(first, second),
        math.dist(second, third),
        math.dist(third, fourth),
        math.dist(fourth, first),
    ]


@dataclass(frozen=True, slots=True)
class _Layout:
    """The warped patch of a marker with ``marker_size`` inner cells a side, and every window
    read from it: where each lies in the patch's integral image (flattened), in one table
    (``windows``) that one gather reads; in its order, the own grid's cell cores (row by row),
    the marker cells' cores again and every finer grid's (whose spreads the ``grid`` rule
    compares: from ``spread_start`` on, ``spread_windows``), then the seams between the marker
    cells (from ``seams_start`` on, :func:`_seams`)."""

    side_px: int  # the patch's side: the marker, its border and one ring of cells
    target: npt.NDArray[np.float32]  # the marker's corners in the patch
    ring: Mask
    # the own grid's cells of the ring, of the border, inside the border and not in the ring,
    # as flat indices in row-major order (what indexing with the masks gives, faster)
    ring_cells: npt.NDArray[np.intp]
    border_cells: npt.NDArray[np.intp]
    inner_cells: npt.NDArray[np.intp]
    marker_cells: npt.NDArray[np.intp]
    own_cores: tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]  # own grid, one axis
    windows: npt.NDArray[np.intp]  # (4, windows): each window's corners (_CORNER_SIGNS)
    area: Floats  # pixels of each window
    spread_start: int
    spread_windows: npt.NDArray[np.intp]  # (4, cores): ``windows`` of the spreads' cores
    spread_area: Floats
    finer_starts: npt.NDArray[np.intp]  # where each finer grid's cores start after the marker's
    finer_cells: tuple[int, ...]  # how many cores each finer grid has
    seams_start: int
    # the marker cells each seam's window covers (flat indices of the own grid, a side's two
    # cells repeated to four)
    seam_members: npt.NDArray[np.intp]
    # each ring cell's (border cell, inner cell) pairs of :func:`_local_quiet`, grouped by ring
    # cell in ``ring_cells``' order: the ring cell, the border cell and the inner cell as flat
    # indices of the own grid, the inner cell also as its index in ``inner_cells``
    pair_ring: npt.NDArray[np.intp]
    pair_border: npt.NDArray[np.intp]
    pair_inner: npt.NDArray[np.intp]
    pair_code: npt.NDArray[np.intp]
    pair_starts: npt.NDArray[np.intp]  # where each ring cell's pairs start
    # for each inner cell (rows, ``inner_cells``' order): which cells of the own grid within
    # one cell of it may be dark (border or inner), and which inner cells lie within
    # LEVEL_WHITE_REACH of it (columns: ``inner_cells``' order); the cell itself left out
    near_dark: Floats
    near_inner: Floats


def _cores(start: int, stop: int, cells: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """First and last-plus-one pixel of the central half of each of ``cells`` cells that
    divide [start, stop)."""
    width = (stop - start) / cells
    index = np.arange(cells)
    low = np.rint(start + (index + 0.25) * width).astype(np.intp)
    high = np.maximum(np.rint(start + (index + 0.75) * width).astype(np.intp), low + 1)
    return low, high


@cache
def _layout(marker_size: int) -> _Layout:
    # the marker spans at least FINEST_CELL_PX a cell of the finest grid (9 cells for 7X7)
    finest = GRID_SIZES[-1] + 2
    cell = max(FINEST_CELL_PX, math.ceil(FINEST_CELL_PX * finest / (marker_size + 2)))
    cells = marker_size + 4
    side = cells * cell
    ring = np.zeros((cells, cells), bool)
    ring[0, :] = ring[-1, :] = ring[:, 0] = ring[:, -1] = True
    inner = np.zeros((cells, cells), bool)
    inner[2:-2, 2:-2] = True
    lo, hi = cell, (cells - 1) * cell
    target = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], np.float32)
    grids = [_cores(0, side, cells)]
    grids += [_cores(lo, hi, size + 2) for size in GRID_SIZES if size > marker_size]
    # each window's top, bottom, left and right rows and columns
    own = _core_windows(*grids[0])
    marker = np.flatnonzero(~ring)
    finer = [_core_windows(*grid) for grid in grids[1:]]
    seam_members, seams = _seams(cells, side)
    parts = [own, own[:, marker], *finer, seams]
    bounds = np.concatenate(parts, axis=1)
    top, bottom, left, right = bounds
    stride = side + 1  # the integral image's row length
    windows = np.stack(
        [bottom * stride + right, top * stride + right, bottom * stride + left, top * stride + left]
    )
    area = ((bottom - top) * (right - left)).astype(np.float64)
    spread_start = cells * cells
    seams_start = bounds.shape[1] - seams.shape[1]
    finer_cells = [grid.shape[1] for grid in finer]
    pairs = _local_pairs(ring, inner)
    near_dark, near_inner = _neighbours(ring, inner)
    return _Layout(
        side,
        target,
        ring,
        np.flatnonzero(ring),
        np.flatnonzero(~ring & ~inner),
        np.flatnonzero(inner),
        marker,
        grids[0],
        windows,
        area,
        spread_start,
        np.ascontiguousarray(windows[:, spread_start:seams_start]),
        area[spread_start:seams_start].copy(),
        np.cumsum([0, *finer_cells], dtype=np.intp)[:-1] + marker.size,
        tuple(finer_cells),
        seams_start,
        seam_members,
        *pairs,
        near_dark,
        near_inner,
    )


def _core_windows(low: npt.NDArray[np.intp], high: npt.NDArray[np.intp]) -> npt.NDArray[np.intp]:
    """The cores of a grid whose cells' cores span [low, high) on each axis, row by row: their
    top, bottom, left and right rows and columns, (4, cells)."""
    cells = low.size
    return np.stack(
        [np.repeat(low, cells), np.repeat(high, cells), np.tile(low, cells), np.tile(high, cells)]
    )


def _seams(cells: int, side: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """The seams of the own grid of ``cells`` cells a side in a patch of ``side`` pixels: a
    window half a cell wide centred on the middle of every side two marker cells share and on
    every corner four share; the marker cells each covers (flat indices of the own grid, a
    side's two cells repeated to four), and the windows as :func:`_core_windows` gives them."""
    cell = side / cells
    members: list[list[int]] = []
    centres: list[tuple[float, float]] = []
    for row in range(1, cells - 1):
        for col in range(1, cells - 1):
            for down, right in ((0, 1), (1, 0), (1, 1)):
                if row + down > cells - 2 or col + right > cells - 2:
                    continue  # a ring cell: not the marker's
                block = [
                    (row + r) * cells + col + c for r in range(down + 1) for c in range(right + 1)
                ]
                members.append((block * 2)[:4])
                centres.append(((row + 0.5 + down / 2) * cell, (col + 0.5 + right / 2) * cell))
    centre = np.array(centres)
    low = np.rint(centre - cell / 4).astype(np.intp)
    high = np.rint(centre + cell / 4).astype(np.intp)
    (top, left), (bottom, right) = low.T, high.T
    return np.array(members, np.intp), np.stack([top, bottom, left, right])


def _neighbours(ring: Mask, inner: Mask) -> tuple[Floats, Floats]:
    """The tables ``near_dark`` and ``near_inner`` of :class:`_Layout`."""
    rows, cols = np.indices(ring.shape)
    flat = np.flatnonzero(inner)
    r, c = rows.ravel(), cols.ravel()
    reach = np.maximum(abs(r[flat, None] - r[None, :]), abs(c[flat, None] - c[None, :]))
    itself = reach == 0
    dark = (reach <= 1) & ~itself & ~ring.ravel()[None, :]
    near = ((reach <= LEVEL_WHITE_REACH) & ~itself)[:, flat]
    return dark.astype(np.float64), near.astype(np.float64)


def _local_pairs(
    ring: Mask, inner: Mask
) -> tuple[
    npt.NDArray[np.intp],
    npt.NDArray[np.intp],
    npt.NDArray[np.intp],
    npt.NDArray[np.intp],
    npt.NDArray[np.intp],
]:
    """For every ring cell (row-major order), every pair of a border cell within
    :data:`LOCAL_BORDER_REACH` and an inner cell within :data:`LOCAL_WHITE_REACH` of it
    (Chebyshev distance, in cells): the tables of :class:`_Layout`."""
    cells = ring.shape[0]
    border = ~ring & ~inner
    rows, cols = np.indices(ring.shape)
    inner_flat = np.flatnonzero(inner)
    code_of = np.full(cells * cells, -1, np.intp)
    code_of[inner_flat] = np.arange(inner_flat.size)
    ring_of: list[int] = []
    border_of: list[int] = []
    inner_of: list[int] = []
    starts: list[int] = []
    for index in np.flatnonzero(ring).tolist():
        row, col = divmod(index, cells)
        reach = np.maximum(abs(rows - row), abs(cols - col))
        near_border = np.flatnonzero(border & (reach <= LOCAL_BORDER_REACH)).tolist()
        near_inner = np.flatnonzero(inner & (reach <= LOCAL_WHITE_REACH)).tolist()
        starts.append(len(ring_of))
        for b in near_border:
            for w in near_inner:
                ring_of.append(index)
                border_of.append(b)
                inner_of.append(w)
    return (
        np.array(ring_of, np.intp),
        np.array(border_of, np.intp),
        np.array(inner_of, np.intp),
        code_of[np.array(inner_of, np.intp)],
        np.array(starts, np.intp),
    )


#: How each of a window's four corners in ``_Layout.windows`` counts in its sum over an
#: integral image (bottom-right, top-right, bottom-left, top-left).
_CORNER_SIGNS: Final = (
    np.array([1.0, -1.0, -1.0, 1.0], np.float32),
    np.array([1.0, -1.0, -1.0, 1.0], np.float64),
)


def _window_stats(patch: Gray, layout: _Layout) -> tuple[Floats, Floats]:
    """The mean of every window of ``layout.windows``, and the standard deviation of those
    from ``layout.spread_start`` to ``layout.seams_start`` (the cores whose spreads the
    ``grid`` rule compares), from the patch's integral images."""
    # Every sum here is a whole number. The pixels' (at most 255 a pixel over the patch,
    # twice that while a window's four corners are added) stays below 2**24 on the layouts'
    # patches, so float32, which OpenCV fills faster, holds it exactly; the squares' needs
    # float64. Exact sums: the tables' types change no result.
    sums, squares = cv2.integral2(patch, sdepth=cv2.CV_32F, sqdepth=cv2.CV_64F)
    signs32, signs64 = _CORNER_SIGNS
    # each table's four corners of every window in one gather: (4, windows), summed by sign
    means = (signs32 @ sums.ravel()[layout.windows]) / layout.area  # float64: the area's type
    variance = (signs64 @ squares.ravel()[layout.spread_windows]) / layout.spread_area
    mean = means[layout.spread_start : layout.seams_start]
    variance -= mean * mean
    return means, np.sqrt(np.maximum(variance, 0.0, out=variance), out=variance)


def _median(values: list[float]) -> float:
    ordered = sorted(values)
    middle = len(ordered) // 2
    return ordered[middle] if len(ordered) % 2 else (ordered[middle - 1] + ordered[middle]) / 2


def _inside(gray: Gray, back: Floats, layout: _Layout) -> Mask:
    """Which cells of the own grid have their central part inside the image (``back``: the
    homography from the patch to the image), told with OpenCV's float32 points: the close look
    where :func:`_well_inside` cannot tell."""
    height, width = gray.shape[:2]
    edge = float(layout.side_px - 1)
    outline = cv2.perspectiveTransform(
        np.array([[[0, 0]], [[edge, 0]], [[edge, edge]], [[0, edge]]], np.float32), back
    )
    if (
        (outline >= 0).all()
        and (outline[..., 0] <= width - 1).all()
        and (outline[..., 1] <= height - 1).all()
    ):
        return np.ones(layout.ring.shape, bool)  # the whole grid is inside the image
    low, high = layout.own_cores
    ends = np.stack([low, high - 1], axis=1).astype(np.float32)  # (cells, 2)
    xs, ys = np.meshgrid(ends.reshape(-1), ends.reshape(-1))
    points = np.stack([xs, ys], axis=-1).reshape(-1, 1, 2)
    cells = low.size
    mapped = cv2.perspectiveTransform(points, back).reshape(cells, 2, cells, 2, 2)
    ok = (mapped >= 0).all(axis=-1) & (mapped[..., 0] <= width - 1) & (mapped[..., 1] <= height - 1)
    return np.asarray(ok.all(axis=(1, 3)), bool)


#: How far inside the image the patch's outline must map for :func:`_well_inside` to say so
#: without OpenCV's float32 points, pixels: far more than their rounding, and than that of the
#: inverse homography :func:`_inverse` computes.
_INSIDE_MARGIN_PX: Final = 0.01


def _well_inside(back: Matrix, edge: float, width: int, height: int) -> bool:
    """Whether the patch's four corners (0 and ``edge`` on each axis) map through ``back``
    clearly inside the image: the common case, told without OpenCV (plain arithmetic on the
    3 x 3 matrix). False means "look closer", not "outside"."""
    (a, b, c), (d, e, f), (g, h, k) = back
    low_x, low_y = _INSIDE_MARGIN_PX, _INSIDE_MARGIN_PX
    high_x, high_y = width - 1 - _INSIDE_MARGIN_PX, height - 1 - _INSIDE_MARGIN_PX
    for x, y in ((0.0, 0.0), (edge, 0.0), (edge, edge), (0.0, edge)):
        w = g * x + h * y + k
        if abs(w) < 1e-9:
            return False
        u, v = (a * x + b * y + c) / w, (d * x + e * y + f) / w
        if not (low_x <= u <= high_x and low_y <= v <= high_y):
            return False
    return True


def _inverse(matrix: Floats) -> Matrix | None:
    """The inverse of the 3 x 3 ``matrix`` scaled to 1 at the bottom right (the form
    ``cv2.getPerspectiveTransform`` gives), in plain arithmetic; None when that entry is 0."""
    (a, b, c), (d, e, f), (g, h, k) = matrix.tolist()
    # the adjugate (the inverse up to the determinant) over its bottom-right entry
    scale = a * e - b * d
    if scale == 0.0:
        return None
    return (
        ((e * k - f * h) / scale, (c * h - b * k) / scale, (b * f - c * e) / scale),
        ((f * g - d * k) / scale, (a * k - c * g) / scale, (c * d - a * f) / scale),
        ((d * h - e * g) / scale, (b * g - a * h) / scale, 1.0),
    )


def _ring_inside(
    gray: Gray, quad: npt.NDArray[np.float32], warp: Floats, layout: _Layout
) -> Mask | None:
    """Which of the own grid's ring cells (``layout.ring_cells``' order) have their central
    part inside the image, None when all have (``warp``: the homography from the image to the
    patch of the marker at ``quad``)."""
    back = _inverse(warp)
    # this inverse differs from OpenCV's homography by rounding, far below _well_inside's
    # margin: when it tells "well inside", OpenCV's would have told so too
    if back is not None and _well_inside(back, layout.side_px - 1.0, gray.shape[1], gray.shape[0]):
        return None
    exact = np.asarray(cv2.getPerspectiveTransform(layout.target, quad), np.float64)
    inside = _inside(gray, exact, layout).ravel()
    return np.asarray(inside[layout.ring_cells], bool)


def _local_quiet(grid: Floats, white: Mask, inside: Mask | None, layout: _Layout) -> float | None:
    """The median over the ring cells inside the image (``inside``, None: all) of each one's
    level between a border cell next to it (0) and a white inner cell near it (1) (``white``:
    which inner cells are white, ``layout.inner_cells``' order), the pair that puts it nearest
    1: the light a ring cell shares with some marker cells beside it. None when no ring cell
    has such a pair."""
    ring = grid[layout.pair_ring]
    border = grid[layout.pair_border]
    span = grid[layout.pair_inner] - border
    valid = white[layout.pair_code] & (span >= LOCAL_CONTRAST_MIN)
    level = (ring - border) / np.maximum(span, LOCAL_CONTRAST_MIN)
    below = np.maximum.reduceat(
        np.where(valid & (level <= 1.0), level, -np.inf), layout.pair_starts
    )
    above = np.minimum.reduceat(np.where(valid & (level >= 1.0), level, np.inf), layout.pair_starts)
    best = np.where(above - 1.0 < 1.0 - below, above, below)
    keep = np.isfinite(best)
    if inside is not None:
        keep &= inside
    values = best[keep].tolist()
    return _median(values) if values else None


@dataclass(frozen=True, slots=True)
class _Code:
    """What a marker's white inner cells fix of its reading, built once a code (:func:`_code`):
    which cells are of either colour, the seams between cells of one colour
    (:func:`stroke_excess`) and how many neighbours of either colour each inner cell has
    (:func:`_local_levels`)."""

    white: Mask  # which inner cells are white, row by row
    light_cells: tuple[int, ...]  # the white inner cells, as flat indices of the own grid
    dark_cells: tuple[int, ...]  # the border cells and the other inner cells, the same way
    # per seam of one colour, for each of the four marker cells it covers, the pair of windows
    # (:class:`_Layout`) whose means' difference is how far the seam strays from that cell
    # towards the other colour: (seam, cell) for a dark seam, (cell, seam) for a white one
    seam_pairs: npt.NDArray[np.intp]  # (2, seams x 4)
    is_dark: Floats  # the own grid, 1.0 but for the white inner cells
    is_white: Floats  # the inner cells, 1.0 for the white ones
    dark_norm: Floats  # each inner cell's dark cells next to it (at least 1)
    white_norm: Floats  # each inner cell's white inner cells near it (at least 1)
    counted: Mask  # which inner cells have both


#: Codes whose :class:`_Code` is kept (a 7X7 code's takes about 16 kB).
_CODES_KEPT: Final = 512


@lru_cache(maxsize=_CODES_KEPT)
def _code(marker_size: int, white_bytes: bytes) -> _Code:
    """The :class:`_Code` of a marker of ``marker_size`` whose white inner cells are
    ``white_bytes`` (a mask's bytes, row by row)."""
    layout = _layout(marker_size)
    white = np.frombuffer(white_bytes, np.bool_).copy()
    cells = layout.ring.shape[0]
    is_white = white.astype(np.float64)
    is_dark = np.ones(cells * cells)
    is_dark[layout.inner_cells] = 1.0 - is_white
    dark_count = layout.near_dark @ is_dark
    white_count = layout.near_inner @ is_white
    light_grid = np.zeros(cells * cells, bool)
    light_grid[layout.inner_cells] = white
    members = layout.seam_members
    kind = light_grid[members]
    dark, light = np.flatnonzero(~kind.any(axis=1)), np.flatnonzero(kind.all(axis=1))
    seam = np.repeat(layout.seams_start + np.arange(len(members)), 4).reshape(-1, 4)
    pairs = np.stack(
        [
            np.concatenate([seam[dark], members[light]]).ravel(),
            np.concatenate([members[dark], seam[light]]).ravel(),
        ]
    )
    dark_grid = np.zeros(cells * cells, bool)
    dark_grid[layout.marker_cells] = True
    dark_grid &= ~light_grid
    return _Code(
        white,
        tuple(np.flatnonzero(light_grid).tolist()),
        tuple(np.flatnonzero(dark_grid).tolist()),
        pairs,
        is_dark,
        is_white,
        np.maximum(dark_count, 1.0),
        np.maximum(white_count, 1.0),
        (dark_count > 0) & (white_count > 0),
    )


def _local_levels(
    grid: Floats, code: Floats, tables: _Code, fallback: Floats, layout: _Layout
) -> Floats:
    """Each inner cell's level between the mean of the dark cells next to it (border cells and
    inner cells not white: 0) and the mean of the white inner cells within
    :data:`LEVEL_WHITE_REACH` of it (1): the light around it, not the whole marker's; where it
    has no such neighbours, or they differ by less than :data:`LOCAL_CONTRAST_MIN`, its level
    in ``fallback``."""
    low = (layout.near_dark @ (grid * tables.is_dark)) / tables.dark_norm
    high = (layout.near_inner @ (code * tables.is_white)) / tables.white_norm
    span = high - low
    ok = tables.counted & (span >= LOCAL_CONTRAST_MIN)
    local = (code - low) / np.maximum(span, LOCAL_CONTRAST_MIN)
    return np.where(ok, local, fallback)


def read_cells(
    gray: Gray,
    corners: npt.NDArray[np.float32],
    marker_size: int,
    side_px: float | None = None,
    bits: Bits | None = None,
    *,
    local_always: bool = False,
) -> Reading:
    """Re-read the marker at ``corners`` (OpenCV's order) with ``marker_size`` inner cells a
    side, as a :class:`Reading` (``side_px``: the quad's mean side, when the caller has it;
    ``bits``: the code OpenCV read, 0/1 per inner cell row by row as
    :func:`dictionary_codes` gives it, which tells the white cells; without it, the cells
    lighter than midway between the border and the lightest cell; ``local_always``: read
    ``quiet_local`` whatever ``quiet`` is, for :func:`measure`)."""
    if side_px is None:
        side_px = sum(quad_sides(corners)) / 4
    layout = _layout(marker_size)
    quad = np.asarray(corners, np.float32)
    warp = np.asarray(cv2.getPerspectiveTransform(quad, layout.target), np.float64)
    patch = np.asarray(cv2.warpPerspective(gray, warp, (layout.side_px, layout.side_px)), np.uint8)
    means, spreads = _window_stats(patch, layout)
    grid = means[: layout.spread_start]  # the own grid's cells, row by row
    # A few dozen values each: plain Python floats from here on, but for the inner cells'
    # levels; a level is (mean - dark) / scale, the same arithmetic as numpy's on arrays.
    border = grid[layout.border_cells].tolist()
    dark = _median(border)
    code = grid[layout.inner_cells]
    values = code.tolist()
    # white cells: the inner cells above the midpoint between the border and the lightest cell
    split = (dark + max(values)) / 2.0
    whites = [value for value in values if value > split]
    light = _median(whites) if whites else dark
    contrast = light - dark
    scale = max(contrast, 1.0)
    inside = _ring_inside(gray, quad, warp, layout)
    cells_ring = grid[layout.ring_cells]
    ring = (cells_ring if inside is None else cells_ring[inside]).tolist()
    quiet = _median([(value - dark) / scale for value in ring]) if ring else 1.0
    white = np.asarray(code > split if bits is None else bits > 0.5, bool)
    quiet_local: float | None = None
    if quiet < QUIET_MIN or local_always:
        local = _local_quiet(grid, white, inside, layout)
        quiet_local = quiet if local is None else local
    border_light = len([value for value in border if (value - dark) / scale > 0.5]) / len(border)
    # the marker cells' spreads first, then the finer grids'
    marker_count = layout.marker_cells.size
    own = float(np.add.reduce(spreads[:marker_count])) / marker_count
    if layout.finer_cells:
        totals = np.add.reduceat(spreads, layout.finer_starts).tolist()
        least = min(total / count for total, count in zip(totals, layout.finer_cells, strict=True))
    else:
        least = own
    grid_ratio = own / max(least, 1e-3)
    return Reading(
        side_px,
        quiet,
        quiet_local,
        contrast,
        border_light,
        grid_ratio,
        marker_size,
        grid,
        white,
        dark,
        means,
        _code(marker_size, white.tobytes()),
    )


@cache
def dictionary_codes(name: str) -> Bits:
    """The codes of the predefined dictionary ``name`` as 0/1 rows of its inner cells, row by
    row, every id in its 4 rotations: rows 4 id .. 4 id + 3, the first as OpenCV's corner
    order reads it."""
    dictionary = aruco_dictionary(name)
    size = int(dictionary.markerSize)
    table = dictionary.bytesList
    rows = [
        np.rot90(dictionary.getBitsFromByteList(table[i : i + 1], size).reshape(size, size), -k)
        for i in range(len(table))
        for k in range(4)
    ]
    return np.asarray(rows, np.float32).reshape(len(table) * 4, size * size)


def id_code(codes: Bits, tag_id: int) -> Bits | None:
    """Id ``tag_id``'s code in ``codes`` (:func:`dictionary_codes`), as OpenCV's corner order
    reads it; None for an id the dictionary does not hold."""
    return codes[4 * tag_id] if 0 <= tag_id < len(codes) // 4 else None


@cache
def min_distance(name: str) -> int:
    """The fewest bits in which an id of dictionary ``name`` differs from another id in any
    rotation."""
    codes = dictionary_codes(name)
    count, cells = len(codes) // 4, codes.shape[1]
    first = codes[0::4]
    same = first @ codes.T + (1.0 - first) @ (1.0 - codes).T  # agreeing bits, every pair
    distance = cells - np.rint(same).astype(int)
    ids = np.arange(count)
    distance.reshape(count, count, 4)[ids, ids, :] = cells + 1
    return int(distance.min())


def decision_margin(levels: Bits, tag_id: int, codes: Bits) -> float:
    """The best other id's score minus ``tag_id``'s, in bits (score: the sum over the cells of
    the distance between the cell's level and the code's bit; ``codes``: see
    :func:`dictionary_codes`)."""
    # sum |l - b| over the cells = sum l + b . (1 - 2 l) for bits b in {0, 1}
    scores = codes @ (1.0 - 2.0 * levels) + float(levels.sum())
    own = float(scores[4 * tag_id])
    if scores.size == 4:
        return math.inf  # a dictionary of one id
    scores[4 * tag_id : 4 * tag_id + 4] = np.inf
    return float(scores.min()) - own


def stroke_excess(reading: Reading) -> float:
    """How far the worst seam between marker cells of one colour (the border's and the dark
    inner cells', or the white cells') strays from those cells towards the other colour: the
    seam's mean over its window (:func:`_seams`) above the lightest of its dark cells' cores,
    or below the darkest of its white cells', over the contrast between the white and the dark
    cells' medians. A printed marker's cells meet edge to edge, so a seam reads as its cells;
    a symbol's strokes do not follow the cell grid: a thin shaft on the seam between two dark
    cells, an arrow head's slant or a gap inside a white cell reads as neither."""
    code = reading.code
    if not code.seam_pairs.size:
        return 0.0
    # a seam's mean above the lightest of its dark cells' is its least excess over them (and
    # the same the other way for white cells): per seam the least of its four pairs
    means = reading.means[code.seam_pairs]
    per_seam = np.minimum.reduce((means[0] - means[1]).reshape(-1, 4), axis=1)
    excess = float(np.maximum.reduce(per_seam))
    values = reading.cells.tolist()
    light = [values[i] for i in code.light_cells]
    dark = [values[i] for i in code.dark_cells]
    contrast = _median(light) - _median(dark) if light and dark else reading.contrast
    return excess / max(contrast, 1.0)
