"""Rectangles of a frame to read again: around a quad, and merged so no pixel is read twice."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: (x0, y0, x1, y1) in pixels, end exclusive.
Rect = tuple[int, int, int, int]


def side(quad: npt.NDArray[np.float32]) -> float:
    """The larger extent of a quad's bounding box, pixels."""
    return float(np.ptp(quad, axis=0).max())


def around(points: npt.NDArray[np.float32], margin: float, width: int, height: int) -> Rect:
    """The bounding box of ``points`` grown by ``margin`` on every side, clipped to the frame."""
    low = points.min(axis=0)
    high = points.max(axis=0)
    x0 = max(0, int(low[0] - margin))
    y0 = max(0, int(low[1] - margin))
    x1 = min(width, int(high[0] + margin) + 2)
    y1 = min(height, int(high[1] + margin) + 2)
    return x0, y0, x1, y1


def overlap(a: Rect, b: Rect) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def merge(rects: list[Rect]) -> list[Rect]:
    """Rectangles merged until none overlaps another (each pixel is read once); empty ones
    are left out."""
    merged = [r for r in rects if r[0] < r[2] and r[1] < r[3]]
    changed = True
    while changed:
        changed = False
        for i in range(len(merged)):
            for j in range(i + 1, len(merged)):
                a, b = merged[i], merged[j]
                if overlap(a, b):
                    merged[i] = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                    del merged[j]
                    changed = True
                    break
            if changed:
                break
    return merged
