"""Tag pose and distance from camera intrinsics and the tag's physical size.

Images are assumed rectified (the ZED wrapper publishes rectified left images), so lens
distortion is ignored. The pose is OpenCV's IPPE_SQUARE solution of the four corners, or
SQPNP's where IPPE_SQUARE's does not reproject onto them.

A square seen small or nearly face-on has two poses that put its corners almost equally well
(IPPE's two solutions, mirror images about the line of sight): the corners' noise decides
between them, and the wrong one is a pose tilted the other way, tens of degrees off. A pose is
marked ``ambiguous`` when the second solution's RMS reprojection error is below
:data:`AMBIGUITY_RATIO` times the first's plus :data:`AMBIGUITY_MARGIN` over the tag's mean
side in pixels (the corners' noise grows as the tag shrinks: a fixed margin marks too many
large tags or too few small ones), and it turns :data:`AMBIGUITY_MIN_DEG` or more away from
the first; both errors are kept. The thresholds are set from ``zenoh-perception bench
--poses`` (docs/benchmarks.md, "Poses").
"""

from __future__ import annotations

import functools
import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, replace
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
    #: IPPE's other solution fits the corners about as well and is turned the other way.
    ambiguous: bool = False
    #: RMS reprojection errors (pixels) of this solution and of IPPE's other one (None: no
    #: other solution, as from SQPNP).
    errors: tuple[float, float] | None = None
    #: IPPE's other solution (rvec, tvec), for a caller that can choose between them.
    other: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(self.tvec))


@functools.lru_cache(maxsize=64)
def _object_points(size_m: float) -> npt.NDArray[np.float64]:
    """The tag's corners in its own frame (read only: shared between calls)."""
    half = size_m / 2.0
    points = np.array(
        [[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]],
        dtype=np.float64,
    )
    points.flags.writeable = False
    return points


#: A solution whose corners reproject farther than this from the detected ones (pixels) is
#: not trusted: IPPE_SQUARE can return the identity rotation, or NaN, for an exactly
#: fronto-parallel, noise-free quad.
MAX_REPROJECTION_PX = 1.0
#: Ambiguous: the second solution's RMS error below this times the first's ...
AMBIGUITY_RATIO: Final = 1.5
#: ... plus this over the tag's mean side (px^2 / px: 0.05 px on a 10 px tag, 0.005 px on a
#: 100 px one) ...
AMBIGUITY_MARGIN: Final = 0.5
#: ... and the two rotations this many degrees apart or more (closer, neither is a flip).
AMBIGUITY_MIN_DEG: Final = 15.0


def _vector(values: npt.ArrayLike) -> tuple[float, float, float]:
    x, y, z = np.asarray(values, np.float64).ravel().tolist()
    return (x, y, z)


def _largest_offset(
    object_points: npt.NDArray[np.float64],
    image_points: npt.NDArray[np.float64],
    camera: npt.NDArray[np.float64],
    rotation: npt.ArrayLike,
    translation: npt.ArrayLike,
) -> float:
    """How far (pixels) the farthest corner reprojects from ``image_points``; inf for a
    solution that is not finite."""
    rvec = np.asarray(rotation, np.float64)
    tvec = np.asarray(translation, np.float64)
    if not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return math.inf
    projected, _ = cv2.projectPoints(object_points, rvec, tvec, camera, None)
    error = float(np.abs(projected.reshape(4, 2) - image_points).max())
    return error if math.isfinite(error) else math.inf


def _mean_side(image_points: npt.NDArray[np.float64]) -> float:
    """The quad's mean side (pixels), at least a pixel."""
    corners: list[list[float]] = image_points.tolist()
    return max(sum(math.dist(corners[i], corners[i - 3]) for i in range(4)) / 4.0, 1.0)


#: OpenCV's RMS reprojection error is the corners' offsets' L2 norm over sqrt(2 x 4): no
#: corner's x or y is farther off than this times it.
_RMS_TO_LARGEST: Final = math.sqrt(8.0)


def _ippe(
    object_points: npt.NDArray[np.float64],
    image_points: npt.NDArray[np.float64],
    camera: npt.NDArray[np.float64],
) -> tuple[float, Pose] | None:
    """IPPE_SQUARE's best solution, marked ambiguous as the module says, with its largest
    corner offset (bounded by its RMS error where that proves it within
    :data:`MAX_REPROJECTION_PX`); None when it has no finite solution."""
    try:
        count, rvecs, tvecs, rms = cv2.solvePnPGeneric(
            object_points, image_points, camera, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
    except cv2.error:
        return None
    if count < 1:
        return None
    errors: list[float] = np.asarray(rms, np.float64).ravel().tolist()
    # a finite RMS error is a finite solution's: its reprojected corners are finite
    if errors and math.isfinite(errors[0]) and _RMS_TO_LARGEST * errors[0] <= MAX_REPROJECTION_PX:
        offset = _RMS_TO_LARGEST * errors[0]
    else:
        offset = _largest_offset(object_points, image_points, camera, rvecs[0], tvecs[0])
    if not math.isfinite(offset):
        return None
    rvec, tvec = _vector(rvecs[0]), _vector(tvecs[0])
    if count < 2 or len(errors) < 2 or not math.isfinite(errors[0] + errors[1]):
        return offset, Pose(rvec, tvec)
    first, second = errors[0], errors[1]
    other = (_vector(rvecs[1]), _vector(tvecs[1]))
    apart = rotation_angle_deg(rvec, other[0])
    ambiguous = (
        second < AMBIGUITY_RATIO * first + AMBIGUITY_MARGIN / _mean_side(image_points)
        and apart >= AMBIGUITY_MIN_DEG
    )
    return offset, Pose(rvec, tvec, ambiguous, (first, second), other)


def _sqpnp(
    object_points: npt.NDArray[np.float64],
    image_points: npt.NDArray[np.float64],
    camera: npt.NDArray[np.float64],
) -> tuple[float, Pose] | None:
    """SQPNP's solution with its largest corner offset; None when it does not solve."""
    try:
        ok, rvec, tvec = cv2.solvePnP(
            object_points, image_points, camera, None, flags=cv2.SOLVEPNP_SQPNP
        )
    except cv2.error:
        return None  # degenerate corners (SQPNP refuses collinear points)
    offset = _largest_offset(object_points, image_points, camera, rvec, tvec) if ok else math.inf
    if not math.isfinite(offset):
        return None
    return offset, Pose(_vector(rvec), _vector(tvec))


def estimate_pose(
    corners: npt.NDArray[np.floating], size_m: float, intrinsics: Intrinsics
) -> Pose | None:
    """Pose of a square tag of edge ``size_m`` seen at ``corners``; None if it cannot be solved.

    IPPE_SQUARE's best solution (marked ambiguous or not) where its corners reproject within
    MAX_REPROJECTION_PX of ``corners``; otherwise whichever of it and SQPNP's reprojects
    closest.
    """
    if size_m <= 0.0:
        return None
    image_points = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    if not math.isfinite(float(image_points.sum())):  # a NaN or an infinity in the sum
        return None
    object_points = _object_points(size_m)
    camera = intrinsics.matrix()
    ippe = _ippe(object_points, image_points, camera)
    if ippe is not None and ippe[0] <= MAX_REPROJECTION_PX:
        return ippe[1]
    found = [s for s in (ippe, _sqpnp(object_points, image_points, camera)) if s is not None]
    return min(found, key=lambda s: s[0])[1] if found else None


#: The last clear pose chooses an ambiguous pose's solution only when the nearer one is within
#: this many degrees of it: farther, the tag has turned since or that pose was off, and IPPE's
#: own choice stands.
MEMORY_NEAR_DEG: Final = 20.0


def chosen_by(pose: Pose, anchor: Pose | None) -> Pose:
    """``pose``, or where it is ambiguous and IPPE's other solution is the nearer in rotation
    to ``anchor`` (a clear pose of the same tag a little earlier) and within
    :data:`MEMORY_NEAR_DEG` of it, that solution: still marked ambiguous (the anchor may be
    off), its error first in ``errors``, IPPE's best in ``other``."""
    if not pose.ambiguous or pose.other is None or anchor is None:
        return pose
    near = rotation_angle_deg(anchor.rvec, pose.other[0])
    if near > MEMORY_NEAR_DEG or near >= rotation_angle_deg(anchor.rvec, pose.rvec):
        return pose
    errors = None if pose.errors is None else (pose.errors[1], pose.errors[0])
    return replace(
        pose, rvec=pose.other[0], tvec=pose.other[1], errors=errors, other=(pose.rvec, pose.tvec)
    )


class PoseMemory:
    """The last clear (not ambiguous) pose of each tag of one stream, choosing between the
    solutions of the tag's ambiguous poses after it (:func:`chosen_by`). A clear pose is the
    anchor, never a chosen one: an ambiguous pose that came out flipped would carry its flip
    forward. One stream's frames, one at a time."""

    #: Tags remembered at most: past it, the memory starts again (a stream sees few tags).
    CAPACITY: Final = 1024

    def __init__(self) -> None:
        self._clear: dict[Hashable, Pose] = {}

    def choose(self, tag: Hashable, pose: Pose) -> Pose:
        """``pose`` of ``tag`` (any key naming it: its dictionary and id), as the memory
        chooses it; a clear pose becomes the tag's anchor."""
        if pose.ambiguous:
            return chosen_by(pose, self._clear.get(tag))
        if len(self._clear) >= self.CAPACITY and tag not in self._clear:
            self._clear.clear()
        self._clear[tag] = pose
        return pose


def rotation_angle_deg(first: Sequence[float], second: Sequence[float]) -> float:
    """The angle (degrees) of the rotation from Rodrigues vector ``first`` to ``second``."""
    p, q = quaternion_from_rvec(first), quaternion_from_rvec(second)
    dot = abs(p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3])
    return math.degrees(2.0 * math.acos(min(1.0, dot)))


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
