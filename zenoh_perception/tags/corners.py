"""Sub-pixel corners for a marker OpenCV has already decided: an edge fit along its four sides.

OpenCV's default detector reports the corners of the polygon it fitted to the marker's contour,
about a pixel off the true outer corners of the black border. Here each side is measured
again in the grey image, the way the AprilTag engine refines its quads: samples spread along
the side, at each one the grey profile read across the side (bilinear), the edge placed at
the centre of mass of the profile's dark-to-light step; a line is fitted through those edge
points (total least squares) and the corners are where neighbouring lines cross. The search
reaches 0.7 of a cell to either side: outwards it stays within the quiet zone, inwards within
the black border (the border's inner edge, a cell in, rises the other way and does not weigh);
a second pass searches again around the first pass's lines. A corner that would move farther
than :data:`MAX_MOVE_CELLS` of a cell keeps OpenCV's position.

Measured against exact ground truth (docs/benchmarks.md, "Poses"): about ten times closer to
the true corners than OpenCV's CORNER_REFINE_SUBPIX on tags of 40 px and more, and never
farther than OpenCV's unrefined corners at the sizes, blurs and angles of ``bench --poses``.

Pure: numpy and OpenCV's ``remap`` only.
"""

from __future__ import annotations

import math
import re
from typing import Final

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
#: Spacing of the samples across a side (pixels).
_STEP_PX: Final = 0.5
#: Samples along a side: one every 2 px, at least 3 and at most this many.
_MAX_SAMPLES: Final = 24
_PASSES: Final = 2
#: A sample whose dark-to-light step is below this share of the median sample's is left out.
_WEAK_STEP: Final = 0.5
#: Cells across a marker with its border, when the dictionary is not known: the most any
#: predefined dictionary has (7x7 bits), so that the search and the accepted move stay small.
_DEFAULT_CELLS: Final = 9
#: The next corner's index, and the previous side's.
_NEXT: Final = np.array([1, 2, 3, 0])
_PREVIOUS: Final = np.array([3, 0, 1, 2])


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
    if not np.all(np.isfinite(given)):
        return given, unrefined
    sides = given[_NEXT] - given
    lengths = np.sqrt((sides * sides).sum(1))
    if lengths.min() < 2.0:
        return given, unrefined
    cell = float(lengths.mean()) / cells
    reach = min(max(_REACH_CELLS * cell, _MIN_REACH_PX), _MAX_REACH_PX)
    across = np.arange(-reach, reach + 1e-9, _STEP_PX)
    middles = ((across[:-1] + across[1:]) * 0.5).astype(np.float32)
    samples = int(min(_MAX_SAMPLES, max(3, lengths.min() // 2)))
    along = np.arange(samples) / (samples - 1.0)
    # outward normals: the quad's winding says on which side of each edge the marker lies
    winding = float(np.sum(given[:, 0] * given[_NEXT, 1] - given[_NEXT, 0] * given[:, 1]))
    turn = np.array([1.0, -1.0] if winding > 0 else [-1.0, 1.0])[:, None, None]
    current = given
    for _ in range(_PASSES):
        fitted = _fit_pass(
            gray, current, reach=reach, across=across, middles=middles, along=along, turn=turn
        )
        if fitted is None:
            return given, unrefined
        current = fitted
    moved = np.sqrt(((current - given) ** 2).sum(1))
    refined = np.isfinite(moved) & (moved <= MAX_MOVE_CELLS * cell)
    return np.where(refined[:, None], current, given), refined


def median(values: npt.NDArray[np.generic]) -> float:
    """``float(np.median(values))``, to the bit, without ``np.median``'s overhead (its
    dispatch and mean cost ten times the partition on a hundred values)."""
    flat = values.reshape(-1)
    if flat.dtype.kind != "f":
        flat = flat.astype(np.float64)  # np.median averages whole numbers in float64
    half = flat.size // 2
    if flat.size % 2:
        part = np.partition(flat, (half, -1))
        middle = part[half]
    else:
        part = np.partition(flat, (half - 1, half, -1))
        middle = (part[half - 1] + part[half]) / 2  # in the array's own precision, as np.mean
    return math.nan if np.isnan(part[-1]) else float(middle)


def _fit_pass(
    gray: npt.NDArray[np.uint8],
    quad: npt.NDArray[np.float64],
    *,
    reach: float,
    across: npt.NDArray[np.float64],
    middles: npt.NDArray[np.float32],
    along: npt.NDArray[np.float64],
    turn: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64] | None:
    """One pass of the edge fit around the sides of ``quad``; None where it fails. (x and y
    lead the arrays, (2, 4, ...): numpy is slow on a last axis of 2, and each step is one call
    for both.)"""
    q = quad.T[:, :, None]
    sides = q[:, _NEXT] - q
    lengths = np.sqrt((sides * sides).sum(0))
    normals = sides[::-1] * (turn / lengths)
    # samples along each side, clear of the corners (where the other side's edge is seen)
    margin = np.minimum((reach + 1.0) / lengths, 0.3)
    bases = q + (margin + (1.0 - 2.0 * margin) * along) * sides
    # the grey profile across the side at each sample, read by OpenCV (bilinear)
    maps = (bases[..., None] + across * normals[..., None]).astype(np.float32)
    count, width = along.size, across.size
    profiles = cv2.remap(
        gray,
        maps[0].reshape(4 * count, width),
        maps[1].reshape(4 * count, width),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(4, count, width)
    levels = profiles.astype(np.float32)
    # the edge at the centre of mass of the dark-to-light step outwards
    steps = np.maximum(levels[:, :, 1:] - levels[:, :, :-1], 0.0)
    weights = steps.sum(2)
    # a sample whose step is weaker than half the typical one missed the edge (its reach
    # fell short of it, or something covers it): noise alone would pull the line to it
    usable = weights > _WEAK_STEP * median(weights)
    kept = usable.sum(1)
    if kept.min() < 2:
        return None
    offsets = np.where(usable, (steps @ middles) / np.maximum(weights, 1e-6), 0.0)
    edges = bases + offsets * normals
    # a line through each side's edge points: centroid and principal direction
    centroids = np.where(usable, edges, 0.0).sum(2) / kept
    spread = np.where(usable, edges - centroids[..., None], 0.0)
    sxx, syy = (spread * spread).sum(2)
    sxy = (spread[0] * spread[1]).sum(1)
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    # lines a x + b y = c, a corner where the previous side's line meets its own side's
    a, b = -np.sin(angle), np.cos(angle)
    c = a * centroids[0] + b * centroids[1]
    a0, b0, c0 = a[_PREVIOUS], b[_PREVIOUS], c[_PREVIOUS]
    det = a0 * b - a * b0
    if np.abs(det).min() < 1e-9:
        return None
    return np.stack(((c0 * b - c * b0) / det, (a0 * c - a * c0) / det), axis=1)
