"""Regions around quads, and one marker found twice."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.detect.regions import around, inside, perimeter, same_marker, side
from zenoh_perception.detect.types import Detection


def square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def test_same_marker_needs_the_same_id_and_nearby_centres() -> None:
    quad = square(100, 100, 40).astype(np.float32)
    assert same_marker(Detection(3, quad), Detection(3, quad + 5))
    assert not same_marker(Detection(3, quad), Detection(4, quad))
    assert not same_marker(Detection(3, quad), Detection(3, quad + 30))


def test_side_is_the_larger_extent_of_the_bounding_box() -> None:
    assert side(square(10, 20, 40).astype(np.float32)) == 40.0
    wide = np.array([[0, 0], [50, 5], [48, 20], [2, 18]], dtype=np.float32)
    assert side(wide) == 50.0


def test_around_grows_the_box_and_clips_it_to_the_frame() -> None:
    quad = square(100, 100, 40).astype(np.float32)
    assert around(quad, 10, 640, 480) == (90, 90, 152, 152)
    assert around(quad, 500, 640, 480) == (0, 0, 640, 480)
    corner = square(0, 0, 10).astype(np.float32)
    assert around(corner, 5, 8, 8) == (0, 0, 8, 8)
    # wholly outside the frame: an empty box at its edge, not an inverted one
    x0, y0, x1, y1 = around(square(700, 500, 20).astype(np.float32), 5, 640, 480)
    assert x0 == x1 == 640 and y0 == y1 == 480
    x0, y0, x1, y1 = around(square(-100, -100, 20).astype(np.float32), 5, 640, 480)
    assert x0 == x1 == 0 and y0 == y1 == 0


def test_inside_is_containment_edges_included() -> None:
    frame = (0, 0, 640, 480)
    assert inside((10, 10, 20, 20), frame)
    assert inside(frame, frame)
    assert not inside((630, 10, 641, 20), frame)
    assert not inside((-1, 0, 10, 10), frame)


@given(
    points=st.lists(
        st.tuples(st.floats(-100.0, 800.0), st.floats(-100.0, 600.0)), min_size=1, max_size=6
    ),
    margin=st.floats(0.0, 200.0),
)
def test_around_always_holds_the_points_within_the_frame(
    points: list[tuple[float, float]], margin: float
) -> None:
    # a tracked marker was last seen in the frame: at least one of its points lies in it
    points = [(320.0, 240.0), *points]
    quad = np.asarray(points, dtype=np.float32)
    x0, y0, x1, y1 = around(quad, margin, 640, 480)
    assert 0 <= x0 <= x1 <= 640 and 0 <= y0 <= y1 <= 480
    assert inside((x0, y0, x1, y1), (0, 0, 640, 480))
    for x, y in quad:  # every point of the frame lies in the region, margin included
        if 0 <= x < 640 and 0 <= y < 480:
            assert x0 <= max(0.0, x - margin) + 1 and x < x1
            assert y0 <= max(0.0, y - margin) + 1 and y < y1


def test_perimeter_is_the_length_of_the_four_sides() -> None:
    quad = np.array([[0, 0], [30, 0], [30, 40], [0, 40]], dtype=np.float32)
    assert perimeter(quad) == pytest.approx(140.0)
    tilted = np.array([[0, 0], [3, 4], [-1, 7], [-4, 3]], dtype=np.float32)  # sides 5
    assert perimeter(tilted) == pytest.approx(20.0)
