"""Look-alike and true-tag frames: what they draw."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zenoh_perception_bench.scene import SceneError
from zenoh_perception_bench.scene._raster import aruco_dictionary
from zenoh_perception_bench.scene.lookalikes import (
    DRAWN_KINDS,
    FAMILIES,
    LOOKALIKE_KINDS,
    PICTOGRAMS,
    family,
    lookalike_frame,
    pictogram,
    true_tag_frame,
)


@pytest.mark.parametrize("kind", DRAWN_KINDS)
def test_a_lookalike_frame_is_an_opaque_bgra_image(kind: str) -> None:
    image = lookalike_frame(kind, "DICT_4X4_50", np.random.default_rng(1), 320, 240)
    assert image.shape == (240, 320, 4) and image.dtype == np.uint8
    assert (image[:, :, 3] == 255).all()
    assert image[:, :, :3].std() > 10.0  # something is drawn


def test_the_same_seed_draws_the_same_frame() -> None:
    first = lookalike_frame("keys", "DICT_6X6_250", np.random.default_rng(4))
    again = lookalike_frame("keys", "DICT_6X6_250", np.random.default_rng(4))
    assert np.array_equal(first, again)


def test_an_unknown_kind_is_refused() -> None:
    with pytest.raises(SceneError, match="look-alike kind"):
        lookalike_frame("clouds", "DICT_4X4_50", np.random.default_rng(1))


def test_families_are_one_dictionary_each() -> None:
    assert len({family(d) for d in FAMILIES}) == len(FAMILIES)
    assert family("DICT_4X4_250") == family("DICT_4X4_50") == "DICT_4X4"
    assert family("DICT_APRILTAG_36h11") == "DICT_APRILTAG_36h11"


def test_true_tags_lie_inside_the_frame_with_ids_of_the_dictionary() -> None:
    image, tags = true_tag_frame("DICT_APRILTAG_36h11", np.random.default_rng(2))
    height, width = image.shape[:2]
    count = aruco_dictionary("DICT_APRILTAG_36h11").bytesList.shape[0]
    assert len(tags) >= 10
    for tag in tags:
        assert 0 <= tag.tag_id < count
        assert (tag.corners >= 0).all()
        assert (tag.corners[:, 0] < width).all() and (tag.corners[:, 1] < height).all()


def test_the_bench_kinds_are_drawn_kinds() -> None:
    assert set(LOOKALIKE_KINDS) < set(DRAWN_KINDS)


@pytest.mark.parametrize("symbol", PICTOGRAMS)
def test_a_pictogram_is_light_strokes_in_a_dark_square(symbol: str) -> None:
    art = pictogram(symbol, 30, 220)
    assert art.shape == (64, 64) and art.dtype == np.uint8
    assert set(np.unique(art).tolist()) <= {30, 220}
    assert 0.1 < (art == 220).mean() < 0.6
    assert (art[0, :] == 30).all() and (art[:, 0] == 30).all()  # a dark edge all round


def test_pictograms_on_cardboard_read_as_4x4_ids() -> None:
    dictionary = aruco_dictionary("DICT_4X4_1000")
    detector = cv2.aruco.ArucoDetector(dictionary, cv2.aruco.DetectorParameters())
    rng = np.random.default_rng(3)
    found = 0
    for _ in range(3):
        image = lookalike_frame("pictograms", "DICT_4X4_1000", rng)
        _, ids, _ = detector.detectMarkers(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY))
        found += 0 if ids is None else len(ids)
    assert found > 0  # what the look-alike is for: OpenCV reads ids on it


def test_an_unknown_pictogram_is_refused() -> None:
    with pytest.raises(SceneError, match="pictogram"):
        pictogram("flammable", 30, 220)
