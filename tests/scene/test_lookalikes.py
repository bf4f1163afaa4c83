"""Look-alike and true-tag frames: what they draw."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_perception.scene import SceneError
from zenoh_perception.scene._raster import aruco_dictionary
from zenoh_perception.scene.lookalikes import (
    FAMILIES,
    LOOKALIKE_KINDS,
    family,
    lookalike_frame,
    true_tag_frame,
)


@pytest.mark.parametrize("kind", LOOKALIKE_KINDS)
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
