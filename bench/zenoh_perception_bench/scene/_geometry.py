"""Pinhole camera, marker poses and the small bits of 3D geometry the generator needs."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception_bench.scene._errors import SceneError

#: Default horizontal field of view (degrees), close to a ZED 2 at HD resolutions.
DEFAULT_HFOV_DEG = 90.0

# A marker that faces the camera upright: marker x = camera x, marker y (up) = -camera y,
# marker z (out of the printed face) = -camera z. This is the rotation of pi about x.
R_FACING = np.diag([1.0, -1.0, -1.0])

# Points closer than this to the camera plane are treated as behind the camera.
_NEAR_M = 0.05


def f64(value: object) -> npt.NDArray[np.float64]:
    """`value` as a float64 array (no copy when it already is one)."""
    return np.asarray(value, dtype=np.float64)


@dataclass(frozen=True)
class CameraModel:
    """Ideal pinhole camera (no distortion) in the scene's pixel convention.

    Camera frame: x right, y down, z forward (OpenCV). A camera-frame point (X, Y, Z) projects
    to x = fx * X / Z + cx, y = fy * Y / Z + cy in continuous image coordinates where the centre
    of pixel (row r, col c) is (x=c, y=r).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise SceneError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise SceneError(f"focal lengths must be positive, got fx={self.fx} fy={self.fy}")
        if not (math.isfinite(self.cx) and math.isfinite(self.cy)):
            raise SceneError("principal point must be finite")

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float = DEFAULT_HFOV_DEG) -> CameraModel:
        """Square-pixel camera with the given horizontal field of view, principal point at the
        image centre ((width - 1) / 2, (height - 1) / 2)."""
        if not 1.0 <= hfov_deg <= 179.0:
            raise SceneError(f"hfov_deg must be in [1, 179], got {hfov_deg}")
        fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, fx, fx, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def named(cls, resolution: str, hfov_deg: float = DEFAULT_HFOV_DEG) -> CameraModel:
        """Camera for one of `RESOLUTIONS` ("VGA", "HD720", "HD1080", "HD2K")."""
        try:
            width, height = RESOLUTIONS[resolution]
        except KeyError as err:
            known = ", ".join(RESOLUTIONS)
            raise SceneError(f"unknown resolution {resolution!r} (known: {known})") from err
        return cls.from_hfov(width, height, hfov_deg)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return (self.width, self.height)

    @property
    def matrix(self) -> npt.NDArray[np.float64]:
        """3x3 intrinsic matrix K (a fresh array)."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    def project(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Project camera-frame points (N, 3) to pixels (N, 2). Points must have Z > 0."""
        pts = f64(points).reshape(-1, 3)
        z = pts[:, 2]
        if not np.all(z > 0):
            raise SceneError("cannot project points at or behind the camera (Z <= 0)")
        out = np.empty((pts.shape[0], 2), dtype=np.float64)
        out[:, 0] = self.fx * pts[:, 0] / z + self.cx
        out[:, 1] = self.fy * pts[:, 1] / z + self.cy
        return out

    def ray(self, pixel: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Unit camera-frame direction through a pixel (x, y)."""
        x, y = f64(pixel).reshape(2)
        d = np.array([(x - self.cx) / self.fx, (y - self.cy) / self.fy, 1.0])
        norm: npt.NDArray[np.float64] = d / np.linalg.norm(d)
        return norm

    def contains(self, points: npt.ArrayLike, margin: float = 0.0) -> bool:
        """Whether all pixel points (N, 2) lie in [margin, W-1-margin] x [margin, H-1-margin]."""
        pts = f64(points).reshape(-1, 2)
        return bool(
            np.all(pts[:, 0] >= margin)
            and np.all(pts[:, 0] <= self.width - 1 - margin)
            and np.all(pts[:, 1] >= margin)
            and np.all(pts[:, 1] <= self.height - 1 - margin)
        )


def rot_x(deg: float) -> npt.NDArray[np.float64]:
    """Right-handed rotation about x by `deg` degrees."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(deg: float) -> npt.NDArray[np.float64]:
    """Right-handed rotation about y by `deg` degrees."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(deg: float) -> npt.NDArray[np.float64]:
    """Right-handed rotation about z by `deg` degrees."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rodrigues(rvec: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotation matrix of a rotation vector."""
    mat, _ = cv2.Rodrigues(f64(rvec).reshape(3, 1))
    return f64(mat)


def rvec_of(rotation: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Rotation vector (3,) of a rotation matrix."""
    vec, _ = cv2.Rodrigues(rotation)
    return f64(vec).reshape(3)


def facing_rotation(direction: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotation of an upright square whose face looks back along `direction` (camera frame).

    The marker's z axis points to the camera (-direction), its y axis is as close to "up in the
    image" (camera -y) as possible.
    """
    d = f64(direction).reshape(3)
    z_m = -d / np.linalg.norm(d)
    up = np.array([0.0, -1.0, 0.0])
    x_m = np.cross(up, z_m)
    n = np.linalg.norm(x_m)
    # looking straight up or down: any in-plane x will do
    x_m = np.array([1.0, 0.0, 0.0]) if n < 1e-9 else x_m / n
    y_m = np.cross(z_m, x_m)
    return np.stack([x_m, y_m, z_m], axis=1)


def square_corners(size_m: float) -> npt.NDArray[np.float64]:
    """Corners (4, 3) of a square in its own frame, OpenCV ArUco order and axes.

    Top-left (-s/2, s/2, 0), top-right (s/2, s/2, 0), bottom-right (s/2, -s/2, 0),
    bottom-left (-s/2, -s/2, 0): x right, y up, z out of the printed face. These are the object
    points `cv2.solvePnP(..., flags=cv2.SOLVEPNP_IPPE_SQUARE)` expects.
    """
    h = size_m / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass(frozen=True)
class MarkerPose:
    """A square tag placed in the camera frame.

    `size_m` is the side of the black border square (the quiet zone is extra). `position` is the
    marker centre (x right, y down, z forward, metres). Orientation is either `rvec` (OpenCV
    rotation vector of marker-to-camera, same convention as `cv2.solvePnP` with
    `square_corners`), or yaw/pitch/roll in degrees relative to "upright and facing the camera":
    R = Ry(yaw) @ Rx(pitch) @ Rz(roll) @ R_facing, right-handed rotations about the camera axes
    (positive roll turns the marker clockwise in the image). Give one or the other.
    """

    tag_id: int
    size_m: float
    position: tuple[float, float, float]
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    rvec: tuple[float, float, float] | None = field(default=None)

    def __post_init__(self) -> None:
        if self.tag_id < 0:
            raise SceneError(f"tag_id must be >= 0, got {self.tag_id}")
        if not self.size_m > 0:
            raise SceneError(f"size_m must be > 0, got {self.size_m}")
        if len(self.position) != 3 or not all(math.isfinite(v) for v in self.position):
            raise SceneError(f"position must be 3 finite numbers, got {self.position!r}")
        if self.rvec is not None and (self.yaw_deg, self.pitch_deg, self.roll_deg) != (0, 0, 0):
            raise SceneError("give either rvec or yaw/pitch/roll, not both")

    @property
    def rotation(self) -> npt.NDArray[np.float64]:
        """Marker-to-camera rotation matrix (3, 3)."""
        if self.rvec is not None:
            return rodrigues(self.rvec)
        tilt = rot_y(self.yaw_deg) @ rot_x(self.pitch_deg) @ rot_z(self.roll_deg)
        out: npt.NDArray[np.float64] = tilt @ R_FACING
        return out

    @property
    def tvec(self) -> npt.NDArray[np.float64]:
        """Marker centre in the camera frame (3,)."""
        return f64(self.position).copy()

    def corners_3d(self, size_m: float | None = None) -> npt.NDArray[np.float64]:
        """Camera-frame corners (4, 3) of the square of side `size_m` (default: the marker)."""
        obj = square_corners(self.size_m if size_m is None else size_m)
        out: npt.NDArray[np.float64] = obj @ self.rotation.T + self.tvec
        return out


def in_front(points_3d: npt.NDArray[np.float64]) -> bool:
    """Whether all camera-frame points are safely in front of the camera."""
    return bool(np.all(points_3d[:, 2] > _NEAR_M))
