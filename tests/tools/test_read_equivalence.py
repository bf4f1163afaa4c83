"""tools/read_equivalence.py: the veto's read and the edge fit against another revision."""

from __future__ import annotations

import cv2
import numpy as np

from tools.read_equivalence import compare, results, variants
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator


def test_a_number_that_differs_or_is_missing_is_reported() -> None:
    old = {"frame": [(1, b"")], "frame/0/0": (None, (1.0, 2.0)), "frame/0/1": ("grid", (3.0,))}
    new = {"frame": [(1, b"")], "frame/0/0": (None, (1.0, 2.0000000000000004))}
    assert compare(old, new) == ["frame/0/0", "frame/0/1"]
    assert compare(old, dict(old)) == []


def test_the_variants_jitter_shrink_and_move_the_quad_to_the_image_s_edge() -> None:
    corners = np.array([[100, 100], [140, 102], [138, 141], [99, 139]], np.float32)
    given, jittered, shrunk, moved = variants(corners, (480, 640), 3)
    assert given is corners
    assert 0 < np.abs(jittered - corners).max() <= 1.5
    assert np.allclose(shrunk.mean(axis=0), corners.mean(axis=0))
    shift = moved - corners  # the same along both sides, one axis left as it was
    assert np.allclose(shift, shift[0]) and 0.0 in shift[0]
    assert (moved >= 0.0).all() and moved.min() <= 3.0


def test_every_tag_of_a_frame_is_read_in_each_variant() -> None:
    scenes = SceneGenerator(CameraModel.named("VGA"), seed=3, effects=Effects.realistic())
    image = scenes.random_scene(3, 2).image
    grey = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)
    found = results(iter([("scene", grey, "DICT_4X4_50")]))
    tags = len(found["scene"])
    assert tags == 5
    reads = [key for key in found if key != "scene"]
    assert {key.rsplit("/", 1)[0] for key in reads} == {f"scene/{i}" for i in range(tags)}
    assert 3 * tags <= len(reads) <= 4 * tags
    reason, measures, *_ = found["scene/0/0"]
    assert reason is None and len(measures) == 8
