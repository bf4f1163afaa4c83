"""Boards beside tags: each kind fills half the frame with periodic squares, the tags beside
it on a light background, where OpenCV's default reads them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception_bench.scene.boards import (
    BOARD_KINDS,
    board_scene,
    board_texture,
    busy_board_scene,
)


@pytest.mark.parametrize("kind", BOARD_KINDS)
def test_each_kind_has_dark_and_light_squares_of_about_the_size_asked(kind: str) -> None:
    texture = board_texture(640, 720, 12, kind)
    assert texture.shape == (720, 640)
    assert texture.min() < 70 and texture.max() > 190
    # about one edge every square along the middle row
    row = texture[360].astype(int)
    edges = np.count_nonzero(np.abs(np.diff(row)) > 40)
    assert 640 / 12 / 2 < edges < 640 / 12 * 4


def test_unknown_kinds_are_refused() -> None:
    with pytest.raises(ValueError, match="hexagons"):
        board_texture(64, 64, 8, "hexagons")


@pytest.mark.parametrize("kind", BOARD_KINDS)
def test_the_tags_are_beside_the_board_and_readable(kind: str) -> None:
    scene = board_scene(1280, 720, 10, kind, tags=(3, 7))
    assert scene.image.shape == (720, 1280, 4)
    assert scene.board[:, :640].all() and not scene.board[:, 640:].any()
    for _, corners in scene.markers:
        assert corners[:, 0].min() > 640
    gray = cv2.cvtColor(scene.image, cv2.COLOR_BGRA2GRAY)
    detector = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_4X4_50"))
    _corners, ids, _rejected = detector.detectMarkers(gray)
    assert sorted(ids.ravel().tolist()) == [3, 7]


def test_the_busy_board_covers_most_of_the_frame_its_tags_on_the_strip_beside() -> None:
    scene = busy_board_scene(tags=(3, 7))
    assert scene.image.shape == (720, 1280, 4)
    assert scene.board[:, :1024].all() and not scene.board[:, 1024:].any()
    for _, corners in scene.markers:
        assert corners[:, 0].min() > 1024 and corners[:, 0].max() < 1280
    # the tags are readable where a grid finder paints the board away (a whole read of the
    # frame is what the bench times: over a second)
    gray = cv2.cvtColor(scene.image, cv2.COLOR_BGRA2GRAY)
    detector = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_4X4_50"))
    _corners, ids, _rejected = detector.detectMarkers(np.ascontiguousarray(gray[:, 1000:]))
    assert sorted(ids.ravel().tolist()) == [3, 7]
