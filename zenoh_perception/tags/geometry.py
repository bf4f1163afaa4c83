"""Per-tag geometry: centre, area and the closeness metric.

Conventions: pixel coordinates with (0, 0) at the top-left, x to the right, y down; corners in
the order top-left, top-right, bottom-right, bottom-left of the marker itself.

Closeness metric, in [0, 1], 0 = very close, 1 = far:

- ``area`` (default): ``1 - sqrt(tag_area / image_area)``, tag area from the corner polygon
  (shoelace formula). A tag filling the whole image scores 0, a vanishing one 1. Rover
  navigation code is tuned for this metric (it stops at about 0.93 at 640x480).
- ``distance``: ``distance_m / max_range_m`` from the tag's estimated pose (needs camera
  intrinsics and the tag's physical size).

Both are clamped to [0, 1].
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from zenoh_perception.errors import IntrinsicsError

Corners = npt.NDArray[np.floating]

#: Largest frame width or height the service accepts, pixels (bigger values are corrupt
#: headers); it also bounds every pixel-valued setting.
MAX_DIMENSION: Final = 16384
#: Plausible focal lengths, pixels: a fisheye on a tiny sensor is above the lower bound, a
#: long telephoto lens on the largest accepted frame below the upper one.
FOCAL_PX_MIN: Final = 1.0
FOCAL_PX_MAX: Final = 100_000.0
#: Largest plausible ratio between fx and fy (pixels are not that far from square).
FOCAL_ASPECT_MAX: Final = 4.0


# Plain Python floats: on four points numpy's per-call overhead (np.roll, mean) outweighs the
# arithmetic itself, and these run for every tag of every frame.


def _points(corners: Corners) -> list[list[float]]:
    out: list[list[float]] = np.asarray(corners, dtype=np.float64).reshape(-1, 2).tolist()
    return out


def tag_center(corners: Corners) -> tuple[float, float]:
    """Mean of the four corners, in absolute pixels."""
    pts = _points(corners)
    if len(pts) != 4:
        msg = f"expected 4 corners, got {len(pts)}"
        raise ValueError(msg)
    xs, ys = zip(*pts, strict=True)
    return sum(xs) / 4.0, sum(ys) / 4.0


def polygon_area(corners: Corners) -> float:
    """Area of the corner polygon in square pixels (shoelace formula, orientation-free)."""
    pts = _points(corners)
    twice = 0.0
    for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1], strict=True):
        twice += x0 * y1 - y0 * x1
    return abs(twice) / 2.0


def mean_side(corners: Corners) -> float:
    """Mean length of the four sides of the corner polygon, in pixels."""
    pts = _points(corners)
    return sum(map(math.dist, pts, pts[1:] + pts[:1])) / len(pts)


def clamp_unit(value: float) -> float:
    """Clamp to [0, 1]; NaN counts as far (1)."""
    if math.isnan(value):
        return 1.0
    return min(1.0, max(0.0, value))


def closeness_from_area(tag_area: float, width: int, height: int) -> float:
    """``1 - sqrt(tag_area / image_area)``, clamped to [0, 1]."""
    image_area = float(width) * float(height)
    if image_area <= 0.0:
        return 1.0
    return clamp_unit(1.0 - math.sqrt(max(tag_area, 0.0) / image_area))


def closeness_from_distance(distance_m: float, max_range_m: float) -> float:
    """``distance_m / max_range_m``, clamped to [0, 1]."""
    if max_range_m <= 0.0:
        return 1.0
    return clamp_unit(distance_m / max_range_m)


def distance_to_center(x: float, y: float, width: int, height: int) -> float:
    """Euclidean distance in pixels from (x, y) to the image centre."""
    return math.hypot(x - width / 2.0, y - height / 2.0)


def check_intrinsics(
    fx: float, fy: float, cx: float, cy: float, *, width: int = 0, height: int = 0
) -> None:
    """Raise :class:`IntrinsicsError` unless the pinhole intrinsics are plausible.

    Plausible: finite; ``fx`` and ``fy`` in [``FOCAL_PX_MIN``, ``FOCAL_PX_MAX``] and within a
    factor ``FOCAL_ASPECT_MAX`` of each other; the principal point strictly inside the image
    (``width`` x ``height`` when known, else ``MAX_DIMENSION`` square). A principal point at 0
    is the value of an unset field, not of a real camera.
    """
    values = (fx, fy, cx, cy)
    if not all(math.isfinite(v) for v in values):
        msg = f"intrinsics must be finite numbers, not fx={fx} fy={fy} cx={cx} cy={cy}"
        raise IntrinsicsError(msg)
    for name, focal in (("fx", fx), ("fy", fy)):
        if not FOCAL_PX_MIN <= focal <= FOCAL_PX_MAX:
            msg = f"{name} = {focal} px is outside [{FOCAL_PX_MIN:g}, {FOCAL_PX_MAX:g}]"
            raise IntrinsicsError(msg)
    if max(fx, fy) > FOCAL_ASPECT_MAX * min(fx, fy):
        msg = f"fx = {fx} and fy = {fy} differ by more than a factor {FOCAL_ASPECT_MAX:g}"
        raise IntrinsicsError(msg)
    max_x = float(width) if width > 0 else float(MAX_DIMENSION)
    max_y = float(height) if height > 0 else float(MAX_DIMENSION)
    if not (0.0 < cx < max_x and 0.0 < cy < max_y):
        msg = f"principal point ({cx}, {cy}) is not inside the image (0..{max_x:g}, 0..{max_y:g})"
        raise IntrinsicsError(msg)
