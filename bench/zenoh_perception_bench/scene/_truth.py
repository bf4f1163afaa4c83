"""What a rendered scene holds: its image and the exact truth of every tag and look-alike."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._effects import EffectParams
from zenoh_perception_bench.scene._geometry import CameraModel


def frozen(array: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    out = np.array(array, dtype=np.float64)
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class MarkerTruth:
    """Ground truth of one rendered tag.

    corners: (4, 2) outer corners of the black border, TL, TR, BR, BL in the marker's own frame
    (cv2.aruco order). centre: (2,) projection of the marker's 3D centre (= intersection of the
    diagonals; `corner_mean` is the mean of the corners, what a plain detector reports).
    distance_m: norm of tvec. rvec / tvec: marker-to-camera pose in OpenCV's convention
    (`square_corners(size_m)` object points). visible: all four corners inside the image
    ([0, W-1] x [0, H-1]). occluded: a nearer object overlaps it (drive frames only).
    """

    tag_id: int
    corners: npt.NDArray[np.float64]
    centre: npt.NDArray[np.float64]
    distance_m: float
    size_m: float
    rvec: npt.NDArray[np.float64]
    tvec: npt.NDArray[np.float64]
    visible: bool
    occluded: bool = False

    @property
    def corner_mean(self) -> npt.NDArray[np.float64]:
        """Mean of the four corners (2,)."""
        out: npt.NDArray[np.float64] = self.corners.mean(axis=0)
        return out

    @property
    def side_px(self) -> float:
        """Mean side length of the corner quad in pixels."""
        sides = np.linalg.norm(np.roll(self.corners, -1, axis=0) - self.corners, axis=1)
        return float(sides.mean())


@dataclass(frozen=True, eq=False)
class DistractorTruth:
    """A marker-like object that is NOT a tag. corners: (4, 2) outer corners of its dark core
    square (where a detector would put a false tag); mimic_id: the id whose code pattern it
    hides (None for "decoy"); other fields as in `MarkerTruth`."""

    kind: str
    corners: npt.NDArray[np.float64]
    centre: npt.NDArray[np.float64]
    distance_m: float
    size_m: float
    mimic_id: int | None
    visible: bool

    @property
    def side_px(self) -> float:
        """Mean side length of the core quad in pixels."""
        sides = np.linalg.norm(np.roll(self.corners, -1, axis=0) - self.corners, axis=1)
        return float(sides.mean())


#: Truth of either kind (what the generator's rolling shutter maps to itself).
Truth = TypeVar("Truth", MarkerTruth, DistractorTruth)


@dataclass(frozen=True, eq=False)
class Scene:
    """One synthetic frame: BGRA uint8 (H, W, 4) C-contiguous image plus exact truth."""

    image: npt.NDArray[np.uint8]
    camera: CameraModel
    markers: tuple[MarkerTruth, ...]
    distractors: tuple[DistractorTruth, ...]
    effects: EffectParams
    dictionary: str
    index: int = 0
    time_s: float = 0.0

    @property
    def ids(self) -> tuple[int, ...]:
        """Tag ids of the rendered markers."""
        return tuple(m.tag_id for m in self.markers)

    def gray(self) -> npt.NDArray[np.uint8]:
        """The image converted to single-channel gray (what ArUco detectors consume)."""
        return np.asarray(cv2.cvtColor(self.image, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)
