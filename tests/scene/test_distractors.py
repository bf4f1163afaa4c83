"""Distractors: tag-like objects that are no markers, and fool OpenCV's default detector."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from tests.scene.cases import aruco_detect
from zenoh_perception_bench.scene import (
    CameraModel,
    Effects,
    SceneGenerator,
)


def _near(point: npt.NDArray[np.float64], quads: list[npt.NDArray[np.float64]]) -> bool:
    return any(
        cv2.pointPolygonTest(q.astype(np.float32), (float(point[0]), float(point[1])), False) >= 0
        for q in quads
    )


def test_distractors_are_not_markers_and_fool_the_default_detector() -> None:
    # Measured while writing this: ~90% of code-bearing distractors decode with default
    # parameters (VGA, realistic effects), and about every such scene has a false positive.
    gen = SceneGenerator(CameraModel.named("VGA"), seed=21, effects=Effects.realistic())
    scenes_with_fp = 0
    decoded = total = 0
    n_scenes = 16
    for _ in range(n_scenes):
        scene = gen.random_scene(2, 4, size_m=(0.12, 0.3), distance_m=(0.5, 3.0))
        marker_quads = [m.corners for m in scene.markers]
        for d in scene.distractors:
            assert d.mimic_id is not None and 0 <= d.mimic_id < 50
            assert not _near(d.centre, marker_quads)
        false_positives = [
            quad
            for tag_id, quads in aruco_detect(scene.image).items()
            for quad in quads
            if not _near(quad.mean(axis=0), marker_quads)
        ]
        distractor_quads = [d.corners for d in scene.distractors]
        # every false positive sits on a recorded distractor (clutter alone does not decode)
        assert all(_near(q.mean(axis=0), distractor_quads) for q in false_positives)
        scenes_with_fp += bool(false_positives)
        decoded += len(false_positives)
        total += len(scene.distractors)
    assert scenes_with_fp >= n_scenes // 2
    assert decoded >= total // 2


def test_decoy_distractors_carry_no_code() -> None:
    gen = SceneGenerator(CameraModel.named("VGA"), seed=4)
    scene = gen.random_scene(0, 4, distractor_kinds=("decoy",), distance_m=(0.5, 2.0))
    assert len(scene.distractors) == 4
    assert all(d.kind == "decoy" and d.mimic_id is None for d in scene.distractors)
    assert scene.markers == ()
