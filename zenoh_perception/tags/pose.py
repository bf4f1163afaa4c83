"""Tag pose and distance from camera intrinsics and the tag's physical size.

Images are assumed rectified (the ZED wrapper publishes rectified left images), so lens
distortion is ignored. The pose is OpenCV's IPPE_SQUARE solution of the four corners, or
SQPNP's where IPPE_SQUARE's does not reproject onto them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole intrinsics in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float

    def matrix(self) -> npt.NDArray[np.float64]:
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )


@dataclass(frozen=True, slots=True)
class Pose:
    """Rotation (Rodrigues vector) and translation (metres) of the tag in the camera frame."""

    rvec: tuple[float, float, float]
    tvec: tuple[float, float, float]

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(self.tvec))


def _object_points(size_m: float) -> npt.NDArray[np.float64]:
    half = size_m / 2.0
    return np.array(
        [[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]],
        dtype=np.float64,
    )


#: A solution whose corners reproject farther than this from the detected ones (pixels) is
#: not trusted: IPPE_SQUARE can return the identity rotation, or NaN, for an exactly
#: fronto-parallel, noise-free quad.
MAX_REPROJECTION_PX = 1.0
#: Solvers in the order they are tried: IPPE_SQUARE (made for square markers), then SQPNP.
_SOLVERS = (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_SQPNP)


def estimate_pose(
    corners: npt.NDArray[np.floating], size_m: float, intrinsics: Intrinsics
) -> Pose | None:
    """Pose of a square tag of edge ``size_m`` seen at ``corners``; None if it cannot be solved.

    The first solver's solution whose corners reproject within MAX_REPROJECTION_PX of
    ``corners``; otherwise the one that reprojects closest.
    """
    if size_m <= 0.0:
        return None
    image_points = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    if not np.all(np.isfinite(image_points)):
        return None
    object_points = _object_points(size_m)
    camera = intrinsics.matrix()
    best: tuple[float, Pose] | None = None
    for solver in _SOLVERS:
        try:
            ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera, None, flags=solver)
        except cv2.error:
            continue  # degenerate corners (SQPNP refuses collinear points)
        if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
            continue
        projected, _ = cv2.projectPoints(object_points, rvec, tvec, camera, None)
        error = float(np.abs(projected.reshape(4, 2) - image_points).max())
        if not np.isfinite(error):
            continue
        r, tr = rvec.reshape(3), tvec.reshape(3)
        pose = Pose(
            (float(r[0]), float(r[1]), float(r[2])), (float(tr[0]), float(tr[1]), float(tr[2]))
        )
        if error <= MAX_REPROJECTION_PX:
            return pose
        if best is None or error < best[0]:
            best = (error, pose)
    return None if best is None else best[1]


#: Below this rotation angle (radians) sin(angle / 2) / angle is taken from its Taylor series.
_SMALL_ANGLE: Final = 1e-6


def quaternion_from_rvec(rvec: Sequence[float]) -> tuple[float, float, float, float]:
    """The unit quaternion ``(x, y, z, w)`` (ROS's order, ``w >= 0``) of a Rodrigues rotation
    vector: axis ``rvec / |rvec|``, angle ``|rvec|`` radians."""
    rx, ry, rz = (float(v) for v in rvec)
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    half = angle / 2.0
    # sin(angle / 2) / angle, exact to double precision near 0 as 1/2 - angle^2 / 48
    scale = 0.5 - angle * angle / 48.0 if angle < _SMALL_ANGLE else math.sin(half) / angle
    w = math.cos(half)
    x, y, z = rx * scale, ry * scale, rz * scale
    if w < 0.0:  # angles past pi: the same rotation with w >= 0
        x, y, z, w = -x, -y, -z, -w
    return x, y, z, w
