"""The tracking detector against OpenCV's on frames with real camera effects, every dictionary
family and every tag size: it finds at least what OpenCV finds, and no id where no tag is."""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Sequence

import cv2
import numpy as np
import pytest

from tests.scene.cases import DICTIONARIES, SIZE_NAMES, random_scene_sized, with_camera
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.types import Detection
from zenoh_perception_bench.scene import (
    CameraEffects,
    CameraModel,
    Effects,
    Scene,
    SceneGenerator,
)

_BASE = Effects.realistic()


_CASES: dict[str, Effects] = {
    "colour_cast": with_camera(CameraEffects(colour_cast=(0.7, 1.0)), _BASE),
    "jpeg": with_camera(CameraEffects(jpeg_quality=(40, 60)), _BASE),
    "exposure_gamma": with_camera(
        CameraEffects(exposure_stops=(-2.0, 1.5), black_crush=(0.05, 0.25), gamma=(0.5, 2.0)),
        _BASE,
    ),
    "shadow": with_camera(
        CameraEffects(shadow_probability=1.0, shadow_depth=(0.5, 0.85), shadow_softness=(0.0, 0.3)),
        _BASE,
    ),
    "paper_glare": with_camera(
        CameraEffects(paper_texture=(6.0, 15.0), glare_probability=1.0, glare_strength=(0.4, 1.0)),
        _BASE,
    ),
    "greyscale": with_camera(
        CameraEffects(greyscale_probability=1.0, mono_contrast=(0.3, 0.7), mono_offset=(30, 90)),
        _BASE,
    ),
    "rolling_shutter": with_camera(CameraEffects(rolling_shutter_px=(15.0, 40.0)), _BASE),
    "strong_blur": dataclasses.replace(_BASE, motion_blur_px=(10.0, 16.0), blur_sigma=(1.0, 2.5)),
    "real_camera": Effects.real_camera(),
}


def _true_ids(detections: Sequence[Detection], scene: Scene) -> Counter[int]:
    """Ids of the detections that lie on a tag of that id (mean corner error within
    max(4 px, a tenth of its side)), each tag matched once."""
    free = list(scene.markers)
    out: Counter[int] = Counter()
    for d in detections:
        for m in free:
            error = float(np.linalg.norm(d.corners - m.corners, axis=1).mean())
            if m.tag_id == d.tag_id and error <= max(4.0, 0.1 * m.side_px):
                out[d.tag_id] += 1
                free.remove(m)
                break
    return out


@pytest.mark.parametrize("effect", list(_CASES))
def test_default_detector_finds_what_opencv_finds(effect: str) -> None:
    # every effect with every dictionary family, the size range turning with the dictionary so
    # that each effect meets every size; a fresh detector per frame (independent frames)
    index = list(_CASES).index(effect)
    cam = CameraModel.named("HD720" if effect == "real_camera" else "VGA")
    reference_total = 0
    sizes_seen: set[str] = set()
    for j, dictionary in enumerate(DICTIONARIES):
        size = SIZE_NAMES[(index + j) % len(SIZE_NAMES)]
        gen = SceneGenerator(
            cam, seed=100 * index + j, dictionary=dictionary, effects=_CASES[effect]
        )
        scene = random_scene_sized(gen, size)
        assert scene.markers
        sizes_seen.add(size)
        gray = np.asarray(cv2.cvtColor(scene.image, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)
        reference = _true_ids(OpenCvDetector(dictionary).detect(gray), scene)
        found = _true_ids(make_detector("tracking", dictionary).detect(gray), scene)
        assert reference <= found, (dictionary, size, reference, found)
        reference_total += reference.total()
    assert sizes_seen == set(SIZE_NAMES)
    assert reference_total > 0  # the comparison is not empty


@pytest.mark.parametrize("dictionary", DICTIONARIES)
def test_default_detector_reports_no_id_without_tags(dictionary: str) -> None:
    # a short run of frames with clutter and tag-like decoys but no tag, under real camera
    # effects, through one detector as a stream would feed it
    gen = SceneGenerator(
        CameraModel.named("VGA"), seed=7, dictionary=dictionary, effects=Effects.real_camera()
    )
    detector = make_detector("tracking", dictionary)
    for _ in range(4):
        scene = gen.random_scene(0, 3, distractor_kinds=("decoy",), distance_m=(0.5, 4.0))
        assert not scene.markers and scene.distractors
        assert detector.detect(scene.gray()) == []


@pytest.mark.parametrize("dictionary", ["DICT_4X4_50", "DICT_APRILTAG_16h5"])
def test_default_detector_reports_no_id_on_a_drive_past_decoys(dictionary: str) -> None:
    # video: the detector follows its stream (skips still frames, scans periodically)
    gen = SceneGenerator(
        CameraModel.named("VGA"), seed=1, dictionary=dictionary, effects=Effects.real_camera()
    )
    detector = make_detector("tracking", dictionary)
    frames = list(gen.drive(8, n_tags=0, n_distractors=4, distractor_kinds=("decoy",)))
    assert all(not f.markers for f in frames)
    assert sum(len(f.distractors) for f in frames) > 0
    assert all(detector.detect(f.gray()) == [] for f in frames)
