"""Periodic grids (checkerboards, tiled floors, grid fences) found cheaply and kept from
OpenCV's detector.

A board of squares just above OpenCV's smallest marker offers its ``ArucoDetector`` every
square as a candidate quad: a few thousand on half an HD720 frame, each warped and read,
which costs a few hundred milliseconds. No marker is in those squares, so the squares are
painted over with the grey around them before OpenCV reads the frame; OpenCV still proposes
and decides every marker elsewhere, and nothing is added.

How a grid is told (on the frame at half size, in 16 px cells there):

- dark and light blobs are the pixels clearly below and clearly above their neighbourhood's
  mean (a dead band between them keeps squares that touch at a corner apart);
- a blob is a *square* when it is small (a few pixels to a few hundred), about as wide as
  high, fills enough of its box and holds its own centre (a square with a marker in it does
  not: the marker is its hole);
- a cell is a grid cell when the 3x3 cells around it hold many dark and many light squares,
  squares cover a large part of them and no large dark shape (a marker's border, an object)
  is among them. Only the squares centred in grid cells are painted over, so a marker beside
  a board keeps a margin of untouched pixels around it.

:class:`GridKeeper` runs this only while it pays: on the frame after a read that took long
for the frame's size, and for a few reads after the last grid found (a plain frame amid
boards, a board out of view for a moment); plain frames otherwise cost one clock reading.
A read that took long counts only where it offered OpenCV many candidate quads (a board's
squares give hundreds): a busy machine, which stretches every read's wall time, does not arm
it on frames that hold a few. (The reading thread's CPU time was tried instead: reading that
clock is a system call, at which the thread, just back from OpenCV's read, yields to OpenCV's
threads still spinning for work, 0.4-0.65 ms a frame on a busy machine.)
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

Gray = npt.NDArray[np.uint8]

#: Grey levels a pixel must be below (above) its neighbourhood's mean to be dark (light).
_BAND = 12
#: Side of the neighbourhood the mean is taken over, in half-size pixels.
_MEAN_SIDE = 15
#: Frames smaller than VGA are left whole: OpenCV reads them quickly whatever they show, and
#: at half size their markers are too few pixels to be told from squares.
_MIN_PIXELS = 640 * 480
#: Side of a cell, in half-size pixels (32 px in the frame).
_CELL = 16
#: A square's area (half-size pixels), side and fill of its bounding box.
_MIN_AREA, _MAX_AREA, _MAX_SIDE, _MIN_FILL = 4, 300, 20, 0.35
#: Squares of each shade a grid cell's 3x3 neighbourhood must hold, and the part of it they cover.
_MIN_SQUARES, _MIN_COVER = 6, 0.2
#: Where both shades have squares, the fewer are at least this share of the more.
_BALANCE = 0.5
#: A blob this large (half-size pixels) is a shape or a net, not a square.
_LARGE_AREA = 400
#: A net's area is at most this many times the area of the squares it encloses.
_NET_SHARE = 2.0
#: The margin of a square's box (a fraction of its side) outside which another shade's blob
#: may be centred; inside it, the square has a hole.
_HOLE_MARGIN = 0.2
#: A large blob whose box holds this many squares of the other shade is a net, not a shape.
_NET_SQUARES = 30
#: The part of a 3x3 neighbourhood large shapes may cover.
_MAX_LARGE_COVER = 0.02
#: A whole-frame read costing more than this many nanoseconds a pixel arms the keeper, when it
#: offered OpenCV at least :data:`_COSTLY_CANDIDATES` candidate quads.
_EXPENSIVE_NS_PER_PIXEL = 40.0
_EXPENSIVE_FLOOR_S = 0.015
#: The fewest candidates (markers and rejected quads) of a read that arms the keeper: the
#: HD720 boards of ``bench`` offer 236-2,172, generated frames with look-alikes at most 9, the
#: real corpus's frames at most 125 (a 12-megapixel photo) but for a wood texture's 664.
_COSTLY_CANDIDATES = 100
#: Reads the keeper stays armed for after the last one that found a grid: a board seen on
#: and off (a plain frame between board frames, a robot turning) must not cost a whole
#: unguarded read each time it comes back (hundreds of ms); a look for grids costs a few.
_HOLD_READS = 30


class _Blobs:
    """The 4-connected blobs of a binary picture: which are squares, and per cell of the
    picture the squares centred there, the area they cover and the area of large blobs."""

    def __init__(self, blobs: Gray, cells: tuple[int, int]) -> None:
        count, labels, stats, centroids = cv2.connectedComponentsWithStats(blobs, connectivity=4)
        width, height, area = stats[:, 2], stats[:, 3], stats[:, 4]
        cx = np.clip(centroids[:, 0].astype(np.int64), 0, blobs.shape[1] - 1)
        cy = np.clip(centroids[:, 1].astype(np.int64), 0, blobs.shape[0] - 1)
        square = (
            (area >= _MIN_AREA)
            & (area <= _MAX_AREA)
            & (width <= _MAX_SIDE)
            & (height <= _MAX_SIDE)
            & (np.maximum(width, height) <= 2 * np.minimum(width, height))
            & (area >= _MIN_FILL * width * height)
            & (labels[cy, cx] == np.arange(count))
        )
        square[0] = False  # the background
        rows, cols = cells
        self.labels: npt.NDArray[np.int32] = np.asarray(labels, np.int32)
        self.square = square
        self.stats = stats
        self.cx, self.cy = cx, cy
        # every blob's centre, one pixel each, summed: how many centres lie in a box
        points = np.zeros(blobs.shape, np.uint8)
        points[cy[1:], cx[1:]] = 1
        self.centre_sums = np.asarray(cv2.integral(points, sdepth=cv2.CV_32S), np.int32)
        self.net = np.zeros(count, bool)
        self.cell = np.minimum(cy // _CELL, rows - 1) * cols + np.minimum(cx // _CELL, cols - 1)
        size = rows * cols
        self.squares = np.bincount(self.cell[square], minlength=size).astype(np.float64)
        self.cover = np.bincount(self.cell[square], weights=area[square], minlength=size)
        self.large = np.zeros(size)
        self.holed = np.zeros(count, bool)

    def drop_holed(self, other: _Blobs) -> None:
        """Squares with a blob of ``other``'s shade centred in the middle of their box are not
        squares: a marker's border with its bits, a board's square with a marker in it."""
        x, y, width, height = (self.stats[:, i] for i in range(4))
        left = x + (width * _HOLE_MARGIN).astype(np.int64)
        top = y + (height * _HOLE_MARGIN).astype(np.int64)
        right = x + width - (width * _HOLE_MARGIN).astype(np.int64)
        bottom = y + height - (height * _HOLE_MARGIN).astype(np.int64)
        sums = other.centre_sums
        inside = sums[bottom, right] - sums[top, right] - sums[bottom, left] + sums[top, left]
        holed = self.square & (inside > 0)
        self.holed = holed
        if not holed.any():
            return
        self.square &= ~holed
        self._count()

    def _count(self) -> None:
        """Per cell, the squares centred there and the area they cover."""
        size = len(self.squares)
        area = self.stats[:, 4]
        self.squares = np.bincount(self.cell[self.square], minlength=size).astype(np.float64)
        weights = area[self.square]
        self.cover = np.bincount(self.cell[self.square], weights=weights, minlength=size)

    def drop_enclosed(self, other: _Blobs) -> None:
        """Squares enclosed by one blob of ``other``'s shade that is not a net are not squares
        of a grid: a marker's bits inside its border. A grid's square meets a different blob
        of the other shade on each side (or a net: a floor's tiles in their grout)."""
        x, y, width, height = (self.stats[:, i] for i in range(4))
        rows, cols = self.labels.shape
        left, right = np.clip(x - 2, 0, cols - 1), np.clip(x + width + 1, 0, cols - 1)
        top, bottom = np.clip(y - 2, 0, rows - 1), np.clip(y + height + 1, 0, rows - 1)
        around = np.stack(
            [
                other.labels[self.cy, left],
                other.labels[self.cy, right],
                other.labels[top, self.cx],
                other.labels[bottom, self.cx],
            ],
            axis=1,
        )
        same = (around[:, :, None] == around[:, None, :]).sum(axis=2)
        enclosing = (around > 0) & ~other.net[around] & (same >= 3)
        enclosed = self.square & enclosing.any(axis=1)
        if enclosed.any():
            self.square &= ~enclosed
            self._count()

    def weigh_large(self, other: _Blobs) -> None:
        """Split the large blobs into nets, whose box holds many of ``other``'s squares (a
        floor's grout and its dark tiles, a fence's wires), painted with the squares they
        enclose, and shapes (a marker's border, an object), near which nothing is painted."""
        x, y, width, height, area = (self.stats[:, i] for i in range(5))
        large = np.flatnonzero(area >= _LARGE_AREA)
        large = large[large > 0]  # not the background
        # a small blob with a hole (a marker, its bits in its border) is a shape too
        holed = np.flatnonzero(self.holed)
        self.large = np.bincount(
            self.cell[holed], weights=area[holed], minlength=len(self.large)
        ).astype(np.float64)
        if len(large) == 0:
            return
        ox, oy = other.cx[other.square], other.cy[other.square]
        inside = (
            (ox[None, :] >= x[large, None])
            & (ox[None, :] < (x + width)[large, None])
            & (oy[None, :] >= y[large, None])
            & (oy[None, :] < (y + height)[large, None])
        )
        enclosed = inside.astype(np.float64) @ other.stats[other.square, 4].astype(np.float64)
        # a net is thin between what it encloses; a page's margin around a board is not
        net = (inside.sum(axis=1) >= _NET_SQUARES) & (area[large] <= _NET_SHARE * enclosed)
        self.net[large[net]] = True
        shapes = large[~net]
        self.large += np.bincount(
            self.cell[shapes], weights=area[shapes], minlength=len(self.large)
        )

    def net_cells(self) -> npt.NDArray[np.float64]:
        """Per cell, 1 where a net's pixels cover a tenth of it, else 0."""
        if not self.net.any():
            return np.zeros(len(self.squares))
        rows, cols = self.labels.shape
        cell_rows, cell_cols = -(-rows // _CELL), -(-cols // _CELL)
        padded = np.zeros((cell_rows * _CELL, cell_cols * _CELL), np.uint8)
        padded[:rows, :cols] = self.net[self.labels]
        share = cv2.resize(padded, (cell_cols, cell_rows), interpolation=cv2.INTER_AREA)
        return (np.asarray(share, np.float64).reshape(-1) >= 0.1).astype(np.float64)

    def painted(
        self, grid: npt.NDArray[np.bool_], cells: npt.NDArray[Any]
    ) -> npt.NDArray[np.bool_]:
        """The pixels of the squares centred in a cell where ``grid`` holds, and those of
        nets inside such cells (``cells``: the grid, one value a pixel)."""
        squares = self.square & grid[self.cell]
        painted: npt.NDArray[np.bool_] = np.take(squares, self.labels)
        if self.net.any():
            painted |= np.take(self.net, self.labels) & (cells > 0)
        return painted


def _around(values: npt.NDArray[Any], cells: tuple[int, int]) -> npt.NDArray[np.float64]:
    """Per cell, the sum over its 3x3 neighbourhood (cells past the edge count as zero)."""
    grid = values.reshape(cells).astype(np.float32)
    summed = cv2.boxFilter(grid, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    return np.asarray(summed, np.float64).reshape(-1)


def grid_mask(gray: Gray) -> npt.NDArray[np.bool_] | None:
    """The pixels of ``gray`` on periodic grids' squares (a little grown), or None when
    there are none."""
    height, width = gray.shape[:2]
    if height * width < _MIN_PIXELS:
        return None
    size = (width // 2, height // 2)
    small = np.asarray(cv2.resize(gray, size, interpolation=cv2.INTER_AREA), np.uint8)
    rows, cols = -(-small.shape[0] // _CELL), -(-small.shape[1] // _CELL)
    if rows < 3 or cols < 3:
        return None
    mean = np.asarray(cv2.blur(small, (_MEAN_SIDE, _MEAN_SIDE)), np.uint8)
    cells = (rows, cols)
    dark = _Blobs(np.asarray(cv2.subtract(mean, small) > _BAND, np.uint8), cells)
    light = _Blobs(np.asarray(cv2.subtract(small, mean) > _BAND, np.uint8), cells)
    dark.drop_holed(light)
    light.drop_holed(dark)
    dark.weigh_large(light)
    light.weigh_large(dark)
    dark.drop_enclosed(light)
    light.drop_enclosed(dark)
    area = 9.0 * _CELL * _CELL
    dark_n, light_n = _around(dark.squares, cells), _around(light.squares, cells)
    dark_net, light_net = _around(dark.net_cells(), cells), _around(light.net_cells(), cells)
    # both shades alternate: squares of each, or squares of one in a net of the other (tiles
    # in their grout); a board of one shade's squares alone (a ChArUco board, whose light
    # squares hold markers) is left to OpenCV
    alternate = (
        (np.minimum(dark_n, light_n) >= _BALANCE * np.maximum(dark_n, light_n))
        | ((dark_net > 0) & (light_n >= _MIN_SQUARES))
        | ((light_net > 0) & (dark_n >= _MIN_SQUARES))
    )
    grid = (
        alternate
        & (dark_n + light_n >= 2 * _MIN_SQUARES)
        & (_around(dark.cover + light.cover, cells) >= _MIN_COVER * area)
        & (_around(dark.large + light.large, cells) <= _MAX_LARGE_COVER * area)
    )
    if not grid.any():
        return None
    spread = cv2.resize(
        grid.reshape(cells).view(np.uint8),
        (cols * _CELL, rows * _CELL),
        interpolation=cv2.INTER_NEAREST,
    )
    spread = spread[: small.shape[0], : small.shape[1]]
    painted = dark.painted(grid, spread) | light.painted(grid, spread)
    # grown by a pixel at half size: the edges between squares go too
    grown = cv2.dilate(painted.view(np.uint8), np.ones((3, 3), np.uint8))
    full = cv2.resize(grown, (width, height), interpolation=cv2.INTER_NEAREST)
    return np.asarray(full, bool)


def keep_grids_away(gray: Gray) -> tuple[Gray, npt.NDArray[np.bool_] | None]:
    """``gray`` with its grids' squares painted the grey around them (a copy) and the
    painted pixels; ``gray`` itself and None when there were none."""
    mask = grid_mask(gray)
    if mask is None:
        return gray, None
    side = 2 * _MEAN_SIDE + 1
    around = np.asarray(cv2.blur(gray, (side, side)), np.uint8)
    out = gray.copy()
    np.copyto(out, around, where=mask)
    return out, mask


def on_painted(corners: npt.NDArray[np.float32], mask: npt.NDArray[np.bool_]) -> bool:
    """Whether a marker's corners or centre lie on painted pixels: painting made it, or
    changed it; it is not reported."""
    height, width = mask.shape
    points = np.vstack([corners, corners.mean(axis=0, keepdims=True)])
    cols = np.clip(np.rint(points[:, 0]).astype(np.int64), 0, width - 1)
    rows = np.clip(np.rint(points[:, 1]).astype(np.int64), 0, height - 1)
    return bool(mask[rows, cols].any())


class GridKeeper:
    """Whether to look for grids before a whole-frame read, the frame to read, and which of
    the markers read there to keep.

    Armed for the read after one that cost more than about 40 ns a pixel (15 ms at least) and
    offered OpenCV :data:`_COSTLY_CANDIDATES` candidates or more, and for ``_HOLD_READS`` reads
    after the last frame with a grid; then a quick read disarms it.

    ``armed``: look for grids from the first read (a detector that replaces one whose read
    stalled: the frames that stalled it are likely to come again).
    """

    def __init__(self, *, armed: bool = False) -> None:
        self._hold = 0  # reads left that look for grids first
        self.armed = armed
        self._mask: npt.NDArray[np.bool_] | None = None

    @property
    def armed(self) -> bool:
        """Whether the next read looks for grids first."""
        return self._hold > 0

    @armed.setter
    def armed(self, armed: bool) -> None:
        """Look for grids on the next read (or not), whatever the reads before."""
        self._hold = 1 if armed else 0

    def prepare(self, gray: Gray) -> Gray:
        """The frame OpenCV should read: ``gray``, or a copy with its grids painted over."""
        self._mask = None
        if not self.armed:
            return gray
        image, self._mask = keep_grids_away(gray)
        return image

    def keep(self, corners: npt.NDArray[np.float32]) -> bool:
        """Whether a marker read on the prepared frame is reported (not on painted pixels)."""
        return self._mask is None or not on_painted(corners, self._mask)

    def record(self, seconds: float, pixels: int, candidates: int = _COSTLY_CANDIDATES) -> None:
        """After the read of a frame of ``pixels`` that took ``seconds`` and offered OpenCV
        ``candidates`` quads (markers and rejected candidates)."""
        budget = max(_EXPENSIVE_FLOOR_S, _EXPENSIVE_NS_PER_PIXEL * 1e-9 * pixels)
        if self._mask is not None:
            self._hold = _HOLD_READS  # grids in view: they may well come back
        elif seconds > budget and candidates >= _COSTLY_CANDIDATES:
            # a look on the next frame; a slow read without grids costs one
            self._hold = max(self._hold, 1)
        elif self._hold > 0:
            self._hold -= 1
