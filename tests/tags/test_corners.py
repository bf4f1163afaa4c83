"""Sub-pixel corners by an edge fit along a decided marker's sides, against exact renders."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zenoh_perception.tags.corners import MAX_MOVE_CELLS, marker_cells, refine_corners
from zenoh_perception_bench.poses import render, tag_rotation
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator

DICTIONARY = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
CELLS = 6  # DICT_4X4_50: 4 bits and the border


def _opencv(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grey frame and OpenCV's default corners (4, 2) of its one marker."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    corners, ids, _ = cv2.aruco.ArucoDetector(DICTIONARY).detectMarkers(grey)
    assert ids is not None
    assert len(corners) == 1
    return grey, corners[0].reshape(4, 2)


def _worst(found: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(found - truth, axis=1).max())


def _frame(resolution: str, distance: float, yaw: float, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    rotation = tag_rotation(yaw, yaw / 2.0, 25.0)
    image, truth = render(resolution, rotation, np.array([0.1, -0.05, distance]), 0.7, rng)
    grey, corners = _opencv(image)
    return grey, corners, truth.corners


def test_a_rendered_tag_s_refined_corners_are_closer_to_the_truth_than_opencv_s() -> None:
    # HD720, 3 m (60 px), turned 40 degrees, blurred and noisy: OpenCV is about a pixel off
    grey, corners, truth = _frame("HD720", 3.0, 40.0, seed=1)
    refined, kept = refine_corners(grey, corners, CELLS)
    assert kept.all()
    assert _worst(corners, truth) > 0.5
    assert _worst(refined, truth) < 0.1
    # OpenCV's own sub-pixel refinement of the same corners is not as close
    subpix = cv2.cornerSubPix(
        grey,
        corners.astype(np.float32).reshape(4, 1, 2).copy(),
        (5, 5),
        (-1, -1),
        (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01),
    ).reshape(4, 2)
    assert _worst(refined, truth) < _worst(subpix, truth)


@pytest.mark.parametrize("seed", range(6))
def test_a_far_small_tag_is_not_made_worse(seed: int) -> None:
    # VGA, 7 m: a 13 px tag whose cells are two pixels wide
    grey, corners, truth = _frame("VGA", 7.0, 30.0, seed=seed)
    refined, _ = refine_corners(grey, corners, CELLS)
    assert _worst(refined, truth) <= _worst(corners, truth)


def test_a_corner_that_would_move_more_than_its_share_of_a_cell_keeps_opencv_s() -> None:
    grey, corners, truth = _frame("HD720", 2.0, 20.0, seed=2)
    cell = float(np.linalg.norm(corners[1] - corners[0])) / CELLS
    off = corners.copy()
    off[2] += (MAX_MOVE_CELLS + 0.3) * cell  # a corner pulled out along the diagonal
    refined, kept = refine_corners(grey, off, CELLS)
    assert kept.tolist() == [True, True, False, True]
    np.testing.assert_array_equal(refined[2], off[2])
    assert _worst(refined[[0, 1, 3]], truth[[0, 1, 3]]) < 0.1


def test_a_blank_picture_leaves_the_corners_as_given() -> None:
    grey = np.full((200, 200), 128, np.uint8)
    corners = np.array([[50.0, 50.0], [150.0, 50.0], [150.0, 150.0], [50.0, 150.0]])
    refined, kept = refine_corners(grey, corners, CELLS)
    assert not kept.any()
    np.testing.assert_array_equal(refined, corners)


def test_degenerate_corners_are_returned_as_given() -> None:
    grey = np.zeros((50, 50), np.uint8)
    for corners in (np.full((4, 2), 10.0), np.array([[1, 1], [2, 1], [np.nan, 2], [1, 2]])):
        refined, kept = refine_corners(grey, corners, CELLS)
        assert not kept.any()
        np.testing.assert_array_equal(refined, np.asarray(corners, np.float64))


@pytest.mark.parametrize(
    ("dictionary", "cells"),
    [
        ("DICT_4X4_50", 6),
        ("DICT_7X7_1000", 9),
        ("DICT_ARUCO_ORIGINAL", 7),
        ("DICT_APRILTAG_16h5", 6),
        ("DICT_APRILTAG_25h9", 7),
        ("DICT_APRILTAG_36h11", 8),
        ("DICT_ARUCO_MIP_36h12", 8),
        ("", 9),
    ],
)
def test_cells_across_a_marker_of_each_dictionary(dictionary: str, cells: int) -> None:
    assert marker_cells(dictionary) == cells
    if dictionary:  # as OpenCV draws it: bits and a one-cell border
        bits = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)).markerSize
        assert cells == bits + 2


#: The refined corners of two tags of a generated VGA frame (a large one and one of 9.5 px),
#: to the bit, as the edge fit gave them before it was made cheaper (with OpenCV 5.1's remap:
#: another OpenCV may move the last bits): tag id, corners.
PINNED_CORNERS = [
    (41, [[48.809027481112196, 274.0407746973391], [133.4861571684181, 275.34716329452215],
          [167.45654525324707, 341.0449362347598], [85.35524420769777, 360.62144230196066]]),
    (4, [[133.19112006786602, 106.29911353035976], [137.9266433390258, 118.49575014593846],
         [127.52022549500512, 121.09389909002972], [122.53818571812617, 108.66215325124249]]),
]  # fmt: skip


@pytest.mark.parametrize(("tag_id", "pinned"), PINNED_CORNERS)
def test_the_refined_corners_of_a_few_tags_are_pinned_to_the_bit(
    tag_id: int, pinned: list[list[float]]
) -> None:
    scenes = SceneGenerator(CameraModel.named("VGA"), seed=3, effects=Effects.realistic())
    grey = np.asarray(cv2.cvtColor(scenes.random_scene(3, 2).image, cv2.COLOR_BGRA2GRAY), np.uint8)
    corners, ids, _ = cv2.aruco.ArucoDetector(DICTIONARY).detectMarkers(grey)
    found = [c.reshape(4, 2) for c, i in zip(corners, ids.ravel(), strict=True) if i == tag_id]
    refined, ok = refine_corners(grey, found[0], CELLS)
    assert ok.all()
    assert refined.tolist() == pinned
