"""Sub-pixel corners for a marker OpenCV has already decided: an edge fit along its four sides.

OpenCV's default detector reports the corners of the polygon it fitted to the marker's contour,
about a pixel off the true outer corners of the black border. Here each side is measured
again in the grey image, the way the AprilTag engine refines its quads: samples spread along
the side, at each one the grey profile read across the side (bilinear), the edge placed at
the centre of mass of the profile's dark-to-light step; a line is fitted through those edge
points (least squares of their offsets across the side, each weighed by its step) and the
corners are where neighbouring lines cross. The search reaches 0.7 of a cell to either side,
the cell measured across the side (from the two sides beside it: on a tag seen at a slant the
cells are narrow one way only): outwards it stays within the quiet zone, inwards within the
black border (the border's inner edge, a cell in, rises the other way and does not weigh); a
second pass searches again around the first pass's lines. A corner that would move farther
than :data:`MAX_MOVE_CELLS` of a cell keeps OpenCV's position.

Measured against exact ground truth (docs/benchmarks.md, "Poses"): about ten times closer to
the true corners than OpenCV's CORNER_REFINE_SUBPIX on tags of 40 px and more, four times
closer than OpenCV's unrefined corners at 10-15 px, and farther than those on 4 of 1,909
rendered tags (turned about 60 degrees, one corner 1.4-4 px off) at the sizes, blurs and
angles of ``bench --poses``.

Pure: numpy and OpenCV's ``remap`` and ``subtract`` only. Its cost is per call, not per pixel
(a tag's reads are a few hundred): numpy and OpenCV do the per-sample work in ten calls a pass,
the few numbers of each side's geometry are Python floats.
"""

from __future__ import annotations

import functools
import math
import re
from typing import Final, NamedTuple

import cv2
import numpy as np
import numpy.typing as npt

#: A refined corner farther than this many cells from OpenCV's is not trusted (a side's
#: samples caught something other than the border's edge): OpenCV's corner is kept.
MAX_MOVE_CELLS: Final = 0.75
#: The search across a side reaches this share of a cell either way, within the bounds below
#: (pixels). Measured on tags of 9-200 px: 0.45 of a cell is 2 to 3 times less precise on
#: tags under 40 px (the blurred edge is cut off), 0.9 no better than 0.7.
_REACH_CELLS: Final = 0.7
_MIN_REACH_PX: Final = 1.0
_MAX_REACH_PX: Final = 4.0
#: Spacing of the reads across a side at most (pixels): they span the search evenly.
_STEP_PX: Final = 0.5
#: Samples along a side: one every 2 px, at least 3 and at most this many.
_MAX_SAMPLES: Final = 24
_PASSES: Final = 2
#: A side's least-squares line is singular (fewer than two usable samples) below this.
_SINGULAR: Final = 1e-9
#: A sample whose dark-to-light step is below this share of the median sample's is left out.
_WEAK_STEP: Final = 0.5
#: Cells across a marker with its border, when the dictionary is not known: the most any
#: predefined dictionary has (7x7 bits), so that the search and the accepted move stay small.
_DEFAULT_CELLS: Final = 9


def marker_cells(dictionary: str) -> int:
    """Cells across a marker of ``dictionary`` (an OpenCV name), its black border included."""
    bits = re.search(r"(\d+)X\d+_", dictionary)
    if bits is not None:
        return int(bits.group(1)) + 2
    april = re.search(r"_(\d+)h\d+$", dictionary)
    if april is not None:  # 16h5: 4x4 bits, 25h9: 5x5, 36h10/36h11/36h12: 6x6
        return math.isqrt(int(april.group(1))) + 2
    if dictionary == "DICT_ARUCO_ORIGINAL":
        return 7
    return _DEFAULT_CELLS


def refine_corners(
    gray: npt.NDArray[np.uint8], corners: npt.ArrayLike, cells: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """The corners (4, 2) of a dark-bordered marker of ``cells`` cells across refined by an
    edge fit, and which of them were refined: a corner whose fit failed or moved farther than
    :data:`MAX_MOVE_CELLS` of a cell is returned as given."""
    given = np.asarray(corners, np.float64).reshape(4, 2)
    unrefined = np.zeros(4, np.bool_)
    quad: list[list[float]] = given.tolist()
    if not all(math.isfinite(v) for corner in quad for v in corner):
        return given, unrefined
    lengths = [math.dist(quad[i], quad[i - 3]) for i in range(4)]
    if min(lengths) < 2.0:
        return given, unrefined
    cell = sum(lengths) / (4.0 * cells)
    # across a side the search reaches a share of the cell measured across it (the sides
    # beside it): on a tag seen at a slant the cells are narrow one way only
    reaches = [_reach((lengths[i - 1] + lengths[i - 3]) / (2.0 * cells)) for i in range(4)]
    samples = int(min(_MAX_SAMPLES, max(3, min(lengths) // 2)))
    grid = _grid(samples, int(2.0 * max(reaches) / _STEP_PX) + 1)
    # the outward normal turns each side a quarter turn away from the marker: which way, the
    # quad's winding says
    winding = sum(quad[i][0] * quad[i - 3][1] - quad[i - 3][0] * quad[i][1] for i in range(4))
    turn = 1.0 if winding > 0 else -1.0
    current = quad
    for _ in range(_PASSES):
        fitted = _fit_pass(gray, current, reaches, turn, grid)
        if fitted is None:
            return given, unrefined
        current = fitted
    limit = MAX_MOVE_CELLS * cell
    refined = [math.dist(c, g) <= limit for c, g in zip(current, quad, strict=True)]
    kept = [c if ok else g for c, g, ok in zip(current, quad, refined, strict=True)]
    return np.array(kept, np.float64), np.array(refined, np.bool_)


def _reach(cell: float) -> float:
    return min(max(_REACH_CELLS * cell, _MIN_REACH_PX), _MAX_REACH_PX)


class _Grid(NamedTuple):
    """Where a side's profiles are read, for a number of samples along it and of reads
    across: ``points`` (3, samples x reads) holds 1, the sample's share t of the way along
    the side and the read's index across it; ``moments`` (2, reads - 1) weighs the steps
    between neighbouring reads by 1 and by the index of their middle; ``powers``
    (samples, 3) is 1, t and t^2, for the sums of a least-squares line along the side.
    Built once for each size (cached)."""

    samples: int
    points: npt.NDArray[np.float32]
    moments: npt.NDArray[np.float32]
    powers: npt.NDArray[np.float64]


@functools.lru_cache(maxsize=256)
def _grid(samples: int, reads: int) -> _Grid:
    along = np.arange(samples) / (samples - 1.0)
    across = np.arange(reads, dtype=np.float64)
    points = np.stack(
        (np.ones(samples * reads), np.repeat(along, reads), np.tile(across, samples))
    ).astype(np.float32)
    middles = (across[:-1] + 0.5).astype(np.float32)
    moments = np.stack((np.ones_like(middles), middles))
    powers = np.stack((np.ones(samples), along, along * along), axis=1)
    return _Grid(samples, points, moments, powers)


def _fit_pass(
    gray: npt.NDArray[np.uint8],
    quad: list[list[float]],
    reaches: list[float],
    turn: float,
    grid: _Grid,
) -> list[list[float]] | None:
    """One pass of the edge fit around the sides of ``quad``; None where it fails.

    Side i runs from corner i to corner i + 1; a sample at share t of the way along it (clear
    of the corners, where the other side's edge is seen) reads the grey profile across it, the
    edge is at an offset o along the outward normal, and o = alpha + beta t is fitted by least
    squares: the side's line, crossed with its neighbours' for the corners. The per-side
    geometry is a handful of floats, done in Python; numpy does the per-sample work in a few
    calls (its per-call overhead, not the pixels, is the cost)."""
    count = grid.samples
    width = grid.points.shape[1] // count
    clear = max(reaches) + 1.0
    # per side: first sample (x, y), from it to the last (x, y), outward unit normal (x, y);
    # the map's rows, x of each side then y of each, are its coefficients of (1, t, offset
    # across)
    frames = []
    across_x = []
    across_y = []
    for i, reach in enumerate(reaches):
        (x0, y0), (x1, y1) = quad[i], quad[i - 3]
        sx, sy = x1 - x0, y1 - y0
        length = math.hypot(sx, sy)
        if length < 1e-9:
            return None
        nx, ny = turn * sy / length, -turn * sx / length
        margin = min(clear / length, 0.3)
        ox, oy = x0 + margin * sx, y0 + margin * sy
        ax, ay = (1.0 - 2.0 * margin) * sx, (1.0 - 2.0 * margin) * sy
        step = 2.0 * reach / (width - 1)
        frames.append((ox, oy, ax, ay, nx, ny, reach, step))
        across_x.append((ox - reach * nx, ax, step * nx))
        across_y.append((oy - reach * ny, ay, step * ny))
    maps = np.array(across_x + across_y, np.float32) @ grid.points
    profiles = cv2.remap(
        gray,
        maps[:4].reshape(4 * count, width),
        maps[4:].reshape(4 * count, width),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    # the edge at the centre of mass of the dark-to-light step outwards: per sample the
    # step's weight (row 0) and its moment about the first read (row 1); the steps' (whole
    # grey levels, saturated at 0 by OpenCV: the dark-to-light ones) and their sums (whole
    # numbers and halves) are exact
    steps = cv2.subtract(profiles[:, 1:], profiles[:, :-1])
    sums = grid.moments @ steps.T
    # a sample whose step is weaker than half the typical one missed the edge (its reach
    # fell short of it, or something covers it): noise alone would pull the line to it
    half = 2 * count
    ordered = np.sort(sums[0])  # a hundred values: faster than np.partition's two
    usable = sums[0] > _WEAK_STEP * 0.5 * float(ordered[half - 1] + ordered[half])
    # per side, the sums of a line o = alpha + beta t through the samples' edges by least
    # squares, each sample weighed by its step w (a weak step's centre is the least
    # certain): sum(w), sum(w t), sum(w t^2), and sum(w o), sum(w o t) with o measured from
    # the first read (w o is the step's moment: no division)
    moments, fits = ((sums * usable).reshape(2, 4, count) @ grid.powers).tolist()
    lines = []
    for (ox, oy, ax, ay, nx, ny, reach, step), (n, st, stt), (so, sto, _) in zip(
        frames, moments, fits, strict=True
    ):
        det = n * stt - st * st
        if det <= _SINGULAR * n * n:  # fewer than two usable samples
            return None
        beta = step * (n * sto - st * so) / det
        alpha = (step * so - beta * st) / n - reach
        lines.append((ox + alpha * nx, oy + alpha * ny, ax + beta * nx, ay + beta * ny))
    corners = []
    for i in range(4):
        # corner i: where the previous side's line meets side i's
        (px, py, pdx, pdy), (x, y, dx, dy) = lines[i - 1], lines[i]
        cross = pdx * dy - pdy * dx
        if abs(cross) < 1e-9:
            return None
        share = ((x - px) * dy - (y - py) * dx) / cross
        corners.append([px + share * pdx, py + share * pdy])
    return corners
