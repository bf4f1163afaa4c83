"""Tag pose and distance from camera intrinsics and the tag's physical size.

Images are assumed rectified (the ZED wrapper publishes rectified left images), so lens
distortion is ignored. The pose is OpenCV's IPPE_SQUARE solution of the four corners.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def estimate_pose(
    corners: npt.NDArray[np.floating], size_m: float, intrinsics: Intrinsics
) -> Pose | None:
    """Pose of a square tag of edge ``size_m`` seen at ``corners``; None if it cannot be solved."""
    if size_m <= 0.0:
        return None
    image_points = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    ok, rvec, tvec = cv2.solvePnP(
        _object_points(size_m),
        image_points,
        intrinsics.matrix(),
        None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )
    if not ok:
        return None
    r = rvec.reshape(3)
    t = tvec.reshape(3)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
        return None
    return Pose((float(r[0]), float(r[1]), float(r[2])), (float(t[0]), float(t[1]), float(t[2])))
