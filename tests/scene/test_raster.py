"""Rendering markers: the exact pixel convention, OpenCV's own bitmaps, sub-pixel truth."""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.scene.cases import DICT_4X4_50, aruco_detect
from zenoh_perception_bench.scene import (
    SceneError,
    render_markers,
)


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def test_bitmap_corners_map_to_generate_image_marker_pixels_exactly() -> None:
    # A quad equal to the outline of an S x S bitmap reproduces OpenCV's own bitmap.
    for side in (6, 60):
        quad = _square(-0.5, -0.5, side)
        image = render_markers(side, side, [(7, quad)], quiet_zone_bits=0)
        expected = cv2.aruco.generateImageMarker(DICT_4X4_50, 7, side, borderBits=1)
        assert np.array_equal(image[:, :, 0], expected)
        assert np.all(image[:, :, 3] == 255)


@settings(max_examples=30, deadline=None)
@given(
    x0=st.floats(3.0, 9.0),
    y0=st.floats(3.0, 9.0),
    side=st.floats(12.0, 150.0),
)
def test_edges_are_box_filtered_at_the_true_position(x0: float, y0: float, side: float) -> None:
    image = render_markers(180, 180, [(7, _square(x0, y0, side))], quiet_zone_bits=0)
    dark = (255.0 - image[:, :, 1].astype(np.float64)) / 255.0
    # Rows / columns through the black border integrate to the exact side length.
    row = round(y0 + side / 12.0)
    col = round(x0 + side / 12.0)
    assert dark[row].sum() == pytest.approx(side, abs=0.04)
    assert dark[:, col].sum() == pytest.approx(side, abs=0.04)
    # The pixel straddling the left edge is darkened by exactly the covered area.
    edge_px = math.floor(x0 + 0.5)
    covered = edge_px + 0.5 - x0
    assert dark[row, edge_px] == pytest.approx(covered, abs=0.02)
    assert dark[row, edge_px - 1] == 0.0


@pytest.mark.parametrize("seed", range(6))
def test_subpix_corners_and_default_centre_match_truth(seed: int) -> None:
    rng = np.random.default_rng(seed)
    side = float(rng.uniform(100.0, 260.0))
    x0, y0 = rng.uniform(40.0, 60.0, 2)
    quad = _square(float(x0), float(y0), side)
    tag_id = int(rng.integers(50))
    # (white surround: OpenCV's default detector misses big quiet-zoned tags on darker gray)
    image = render_markers(400, 400, [(tag_id, quad)], background=255)
    refined = aruco_detect(image, subpix=True)
    assert list(refined) == [tag_id]
    assert np.abs(refined[tag_id][0] - quad).max() < 0.3
    default = aruco_detect(image)
    centre = default[tag_id][0].mean(axis=0)
    assert np.linalg.norm(centre - quad.mean(axis=0)) < 0.5


def test_rotated_marker_corner_order_matches_aruco() -> None:
    centre = np.array([200.3, 190.7])
    angle = math.radians(33.0)
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    quad = centre + (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 80.0) @ rot.T
    found = aruco_detect(render_markers(400, 400, [(21, quad)], background=230), subpix=True)
    assert np.abs(found[21][0] - quad).max() < 0.3


def test_render_markers_rejects_bad_input() -> None:
    good = _square(10, 10, 40)
    with pytest.raises(SceneError):
        render_markers(100, 100, [(50, good)])  # DICT_4X4_50 has ids 0..49
    with pytest.raises(SceneError):
        render_markers(100, 100, [(1, good)], dictionary="DICT_NOPE")
    with pytest.raises(SceneError):
        render_markers(100, 100, [(1, good[[0, 2, 1, 3]])])  # self-intersecting
    with pytest.raises(SceneError):
        render_markers(100, 100, [(1, good[:3])])
    with pytest.raises(SceneError):
        render_markers(100, 100, [(1, good)], quiet_zone_bits=-1)
    with pytest.raises(SceneError):
        render_markers(100, 100, [(1, good)], background=np.zeros((5, 5), np.uint8))


def test_render_markers_quiet_zone_and_other_dictionaries() -> None:
    quad = _square(60.2, 60.7, 60.0)  # 6 cells of 10 px
    bright = render_markers(200, 200, [(3, quad)], background=0, quiet_zone_bits=2)
    # quiet zone: 2 cells (20 px) of white around the border, black background beyond
    assert bright[50, 90, 0] == 255  # inside the quiet zone above the marker
    assert bright[35, 90, 0] == 0  # beyond it
    image = render_markers(200, 200, [(5, quad)], dictionary="DICT_5X5_100", background=255)
    params = cv2.aruco.DetectorParameters()
    gray = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    five = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    _, ids, _ = cv2.aruco.ArucoDetector(five, params).detectMarkers(gray)
    assert ids is not None and ids.ravel().tolist() == [5]
