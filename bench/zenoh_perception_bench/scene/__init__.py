"""Synthetic camera scenes with exact ArUco ground truth (pure: numpy + cv2 only).

Pixel convention (exact, used everywhere in this package)
--------------------------------------------------------
Continuous image coordinates: the CENTRE of pixel (row r, col c) is at (x=c, y=r); (0, 0) is
the centre of the top-left pixel, whose area is [-0.5, 0.5) x [-0.5, 0.5). This is OpenCV's
convention (cv2.warpPerspective, cv2.cornerSubPix, cv2.aruco corners).

A marker's corners are the outer corners of its black border square (NOT of the white quiet
zone), ordered top-left, top-right, bottom-right, bottom-left as seen in the marker's own frame,
the order cv2.aruco reports. A marker bitmap of S x S pixels has its outer corners at
(-0.5, -0.5), (S-0.5, -0.5), (S-0.5, S-0.5), (-0.5, S-0.5) in bitmap coordinates; rendering maps
exactly those points to the target quad with a homography and anti-aliases by supersampling
(box filter), so sub-pixel truth is meaningful: a pixel straddling an axis-aligned edge holds
the covered area to ~0.015 and a row across a marker integrates to its side within ~0.025 px
(cv2.cornerSubPix itself lands ~0.1 px inside such corners; their mean is unbiased). `centre`
in the truth is the projection of the 3D marker centre (intersection of the diagonals),
`corner_mean` the mean of the corners (what a plain detector reports as centre).

3D: camera frame x right, y down, z forward; marker frame (OpenCV ArUco) x right, y up, z out of
the printed face, so rvec/tvec are what `cv2.solvePnP(square_corners(size), corners, K, None)`
returns (any solver; IPPE_SQUARE's object points). `distance_m` is the norm of tvec.

Main entry points
-----------------
- `render_markers(width, height, [(id, corners), ...])`: flat exact placement, BGRA, no effects.
- `CameraModel.from_hfov(w, h, hfov_deg)`, `CameraModel.named("HD1080")` (the names of
  `zenoh_perception.resolutions.RESOLUTIONS`).
- `SceneGenerator(camera, dictionary=..., seed=..., effects=Effects.realistic())` with
  `.random_scene(...)`, `.scene_from_poses(...)` and `.drive(...)`, each giving `Scene` objects
  (BGRA image + `MarkerTruth` / `DistractorTruth` tuples).
- `Effects.clean()`, `.realistic()`, `.harsh()` and `.real_camera()`; the last adds what real
  cameras do (`CameraEffects`: coloured light, exposure, shadows, glare, paper grain, greyscale
  sensors, rolling shutter, JPEG). `random_scene(side_px=(min, max))` asks for tag sizes in
  pixels. With a rolling shutter, truth corners and centres are where the sheared image shows
  them and the pose is the one of the middle row.
"""

from __future__ import annotations

from zenoh_perception_bench.scene._camera_effects import CAST_KINDS, CameraEffects, CameraParams
from zenoh_perception_bench.scene._distractors import (
    CODE_DISTRACTOR_KINDS,
    DISTRACTOR_KINDS,
)
from zenoh_perception_bench.scene._effects import BACKGROUND_KINDS, EffectParams, Effects
from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._generator import DistractorPose, SceneGenerator
from zenoh_perception_bench.scene._geometry import (
    DEFAULT_HFOV_DEG,
    CameraModel,
    MarkerPose,
    square_corners,
)
from zenoh_perception_bench.scene._raster import render_markers
from zenoh_perception_bench.scene._truth import DistractorTruth, MarkerTruth, Scene

__all__ = [
    "BACKGROUND_KINDS",
    "CAST_KINDS",
    "CODE_DISTRACTOR_KINDS",
    "DEFAULT_HFOV_DEG",
    "DISTRACTOR_KINDS",
    "CameraEffects",
    "CameraModel",
    "CameraParams",
    "DistractorPose",
    "DistractorTruth",
    "EffectParams",
    "Effects",
    "MarkerPose",
    "MarkerTruth",
    "Scene",
    "SceneError",
    "SceneGenerator",
    "render_markers",
    "square_corners",
]
