"""Scene set-ups shared by the scene and detector tests: still tags facing the camera, camera
effects switched on one at a time, tag sizes in pixels and the dictionary families."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene import (
    CameraEffects,
    CameraModel,
    Effects,
    MarkerPose,
    Scene,
    SceneGenerator,
)

Image = npt.NDArray[np.uint8]
Floats = npt.NDArray[np.float64]


# On, but with every strength at zero: draws the same random numbers as any other camera
# configuration (so scenes share their layout and background with it) and changes no pixel.
NEUTRAL = CameraEffects(shadow_probability=1.0)

# A still camera on a plain background, ink levels 30 and 230 (neither clips when an effect
# adds or takes light): only the effect under test acts.
STILL = Effects(marker_black=(30, 30), marker_white=(230, 230))

#: A small camera (320 x 240, fx = fy = 300): quick to render.
SMALL = CameraModel(320, 240, 300.0, 300.0, 159.5, 119.5)

#: One dictionary of each family OpenCV knows.
DICTIONARIES = (
    "DICT_4X4_50",
    "DICT_5X5_100",
    "DICT_6X6_250",
    "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h11",
    "DICT_ARUCO_MIP_36h12",
)


#: OpenCV's DICT_4X4_50, the dictionary of most scenes here.
DICT_4X4_50 = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
Detections = dict[int, list[Floats]]


def facing(tag_id: int, size_m: float, x: float, y: float, z: float) -> MarkerPose:
    """A marker of ``size_m`` facing the camera upright, its centre at (x, y, z) metres."""
    return MarkerPose(tag_id, size_m, (x, y, z))


def aruco_detect(image: Image, *, subpix: bool = False) -> Detections:
    """OpenCV's detections {id: [corners (4, 2), ...]} of DICT_4X4_50 markers on a BGRA image
    (default parameters; with ``subpix``, sub-pixel corner refinement)."""
    params = cv2.aruco.DetectorParameters()
    if subpix:
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    gray = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    corners, ids, _ = cv2.aruco.ArucoDetector(DICT_4X4_50, params).detectMarkers(gray)
    out: Detections = {}
    if ids is not None:
        for tag_id, quad in zip(ids.ravel(), corners, strict=True):
            out.setdefault(int(tag_id), []).append(np.asarray(quad, np.float64).reshape(4, 2))
    return out


def with_camera(camera: CameraEffects, base: Effects = STILL) -> Effects:
    return dataclasses.replace(base, camera=camera)


def facing_scene(
    camera: CameraEffects, *, seed: int = 0, base: Effects = STILL, cam: CameraModel = SMALL
) -> Scene:
    """One upright tag facing the camera, about 0.55 of the image height, in the middle."""
    gen = SceneGenerator(cam, seed=seed, effects=with_camera(camera, base))
    size = 0.55 * cam.height / cam.fy  # at 1 m
    return gen.scene_from_poses([MarkerPose(7, size, (0.0, 0.0, 1.0))])


def as_float(image: Image) -> Floats:
    return image[:, :, :3].astype(np.float64)


def inside_quad(quad: Floats, shape: tuple[int, ...], grow: float = 1.0) -> npt.NDArray[np.bool_]:
    """Pixels whose centre lies in `quad` scaled by `grow` about its centre."""
    centre = quad.mean(axis=0)
    scaled = centre + (quad - centre) * grow
    mask = np.zeros(shape[:2], dtype=np.uint8)
    cv2.fillPoly(mask, [np.rint(scaled * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
    return mask.astype(bool)


def tag_sizes(height: int) -> dict[str, tuple[tuple[float, float], float]]:
    """Tag size ranges, as (side_px, partial_fraction): tiny, medium, half the frame, and cut
    by the image border."""
    return {
        "tiny": ((9.0, 13.0), 0.0),
        "medium": ((30.0, 120.0), 0.0),
        "half": ((0.4 * height, 0.5 * height), 0.0),
        "border": ((40.0, 0.3 * height), 1.0),
    }


SIZE_NAMES = ("tiny", "medium", "half", "border")


def random_scene_sized(gen: SceneGenerator, size: str) -> Scene:
    side_px, partial = tag_sizes(gen.camera.height)[size]
    if size == "half":  # one tag that big is all a frame holds
        return gen.random_scene(1, 0, side_px=side_px)
    return gen.random_scene(
        4, 2, distractor_kinds=("decoy",), side_px=side_px, partial_fraction=partial
    )
