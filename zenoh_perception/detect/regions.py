"""Rectangles of a frame to read again, around quads; markers found twice, or seen again on
the next frame."""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.types import Detection
from zenoh_perception.tags.geometry import mean_side

#: A marker on the frame before is seen again when its centre moved at most this share of its
#: mean side and its mean side changed at most by this share.
SAME_PLACE: Final = 0.25
SAME_SIZE: Final = 0.2

#: (x0, y0, x1, y1) in pixels, end exclusive.
Rect = tuple[int, int, int, int]


def side(quad: npt.NDArray[np.float32]) -> float:
    """The larger extent of a quad's bounding box, pixels."""
    return float(np.ptp(quad, axis=0).max())


def perimeter(quad: npt.NDArray[np.float32]) -> float:
    """The length of a quad's four sides, pixels."""
    return float(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1).sum())


def around(points: npt.NDArray[np.float32], margin: float, width: int, height: int) -> Rect:
    """The bounding box of ``points`` grown by ``margin`` on every side, clipped to the frame
    (empty, never inverted, when it lies wholly outside)."""
    low = points.min(axis=0)
    high = points.max(axis=0)
    x0 = min(width, max(0, int(low[0] - margin)))
    y0 = min(height, max(0, int(low[1] - margin)))
    x1 = max(x0, min(width, int(high[0] + margin) + 2))
    y1 = max(y0, min(height, int(high[1] + margin) + 2))
    return x0, y0, x1, y1


def inside(a: Rect, b: Rect) -> bool:
    """Whether ``a`` lies within ``b``."""
    return b[0] <= a[0] and b[1] <= a[1] and a[2] <= b[2] and a[3] <= b[3]


def same_marker(a: Detection, b: Detection) -> bool:
    """One marker found twice: same id, centres closer than half its side."""
    if a.tag_id != b.tag_id:
        return False
    distance = float(np.linalg.norm(a.corners.mean(axis=0) - b.corners.mean(axis=0)))
    return distance < 0.5 * side(b.corners)


def seen_again(
    now: Detection, before: Detection, place: float = SAME_PLACE, size: float = SAME_SIZE
) -> bool:
    """Whether ``now`` is the marker ``before`` was on the previous frame of a stream: same id
    and dictionary, its centre moved at most ``place`` times and its mean side changed at most
    ``size`` times ``before``'s mean side."""
    if now.tag_id != before.tag_id or now.dictionary != before.dictionary:
        return False
    side_px = mean_side(before.corners)
    if abs(mean_side(now.corners) - side_px) > size * side_px:
        return False
    shift = np.abs(now.corners.mean(axis=0) - before.corners.mean(axis=0))
    return float(shift.max()) <= place * side_px
