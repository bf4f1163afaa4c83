"""The approach set: frames of a rover closing in on a tag, for the coarse first read.

A tag of :data:`TAG_SIZE_M` grows from :data:`SIDE_PX` [0] to [1] pixels across (log-spaced,
so each size is as common), nearly face on, wandering about the image centre; beside it a
second tag half its size, a little farther, and two look-alikes (a glyph and a bare code of
the dictionary) at about its distance, one of them up to 1.3 times its size (a look-alike
larger than the true tag is what the veto must judge on full-resolution pixels). Motion blur
up to :data:`MOTION_BLUR_PX` and the generator's realistic effects (textured ground,
clutter, noise, lighting). Each frame is independent (its effects drawn afresh), its
truth the tag's side. Pure: numpy and the scene generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene import (
    CameraModel,
    DistractorPose,
    Effects,
    MarkerPose,
    SceneGenerator,
)

#: The approached tag's side, pixels: from, to.
SIDE_PX: Final = (30.0, 400.0)
#: The approached tag's side, metres.
TAG_SIZE_M: Final = 0.2
#: Longest motion blur, pixels.
MOTION_BLUR_PX: Final = 6.0
#: The tag's id, and the second tag's.
TAG_ID: Final = 7
SECOND_ID: Final = 3


@dataclass(frozen=True, slots=True)
class ApproachFrame:
    """One frame of the approach: BGRA pixels and the approached tag's side (pixels)."""

    image: npt.NDArray[np.uint8]
    side_px: float


def approach_frames(resolution: str, count: int, seed: int = 0) -> list[ApproachFrame]:
    """``count`` frames of ``resolution`` (a name of
    :data:`~zenoh_perception.resolutions.RESOLUTIONS`) along one approach (see the module
    documentation), deterministic for ``seed``."""
    camera = CameraModel.named(resolution)
    effects = replace(Effects.realistic(), motion_blur_px=(0.0, MOTION_BLUR_PX))
    scenes = SceneGenerator(camera, seed=seed, effects=effects)
    rng = np.random.default_rng(seed)
    low, high = SIDE_PX
    frames = []
    for index in range(count):
        side = low * (high / low) ** (index / max(1, count - 1))
        z = camera.fx * TAG_SIZE_M / side
        # the tag within a quarter of the image's width of its centre, the others beside it
        reach = 0.25 * camera.width / camera.fx * z
        x = float(rng.uniform(-reach, reach))
        y = float(rng.uniform(-0.5, 0.5)) * reach
        away = math.copysign(1.0, -x) if x else 1.0
        gap = TAG_SIZE_M * 1.6
        markers = [
            MarkerPose(TAG_ID, TAG_SIZE_M, (x, y, z), yaw_deg=float(rng.uniform(-25, 25))),
            MarkerPose(
                SECOND_ID,
                TAG_SIZE_M / 2,
                (x + away * gap, y - TAG_SIZE_M * 0.4, z * 1.2),
                yaw_deg=float(rng.uniform(-25, 25)),
            ),
        ]
        lookalike = TAG_SIZE_M * float(rng.uniform(0.6, 1.3))
        distractors = [
            DistractorPose("glyph", lookalike, (x - away * gap * 1.2, y, z * 1.1), None, 5),
            DistractorPose(
                "bare_code", TAG_SIZE_M * 0.7, (x + away * gap, y + TAG_SIZE_M, z * 1.05), None, 9
            ),
        ]
        scene = scenes.scene_from_poses(markers, distractors)
        frames.append(ApproachFrame(scene.image, side))
    return frames
