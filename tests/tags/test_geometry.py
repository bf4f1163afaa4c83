"""Tag geometry: centre, area, mean side, the closeness metrics and the intrinsics check."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.errors import IntrinsicsError
from zenoh_perception.tags.geometry import (
    check_intrinsics,
    closeness_from_area,
    closeness_from_distance,
    mean_side,
    polygon_area,
    tag_center,
)


def _square(x0: float, y0: float, side: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def test_center_is_the_mean_of_the_corners() -> None:
    corners = np.array([[10.0, 20.0], [30.0, 22.0], [28.0, 40.0], [12.0, 44.0]])
    assert tag_center(corners) == pytest.approx((20.0, 31.5))


def test_area_of_a_square_and_a_rotated_square() -> None:
    assert polygon_area(_square(5, 5, 10)) == pytest.approx(100.0)
    diamond = np.array([[0.0, -5.0], [5.0, 0.0], [0.0, 5.0], [-5.0, 0.0]])
    assert polygon_area(diamond) == pytest.approx(50.0)
    assert polygon_area(diamond[::-1]) == pytest.approx(50.0)  # orientation-free


def test_closeness_reference_values() -> None:
    # A 640x480 frame: a tag of 1/4 of the image area is at 1 - sqrt(1/4) = 0.5.
    assert closeness_from_area(640 * 480 / 4, 640, 480) == pytest.approx(0.5)
    assert closeness_from_area(640 * 480, 640, 480) == 0.0
    assert closeness_from_area(0.0, 640, 480) == 1.0
    # The rover stops at about 0.93 at 640x480: a tag of about 38x38 px.
    side = math.sqrt((1 - 0.93) ** 2 * 640 * 480)
    assert closeness_from_area(side * side, 640, 480) == pytest.approx(0.93)


@given(
    area=st.one_of(st.floats(min_value=-1e12, max_value=1e12), st.just(math.nan)),
    width=st.integers(min_value=0, max_value=10000),
    height=st.integers(min_value=0, max_value=10000),
)
def test_closeness_is_always_in_the_unit_interval(area: float, width: int, height: int) -> None:
    value = closeness_from_area(area, width, height)
    assert 0.0 <= value <= 1.0


@given(st.floats(allow_nan=True), st.floats(allow_nan=True))
def test_distance_closeness_is_clamped(distance: float, max_range: float) -> None:
    assert 0.0 <= closeness_from_distance(distance, max_range) <= 1.0


def test_mean_side_of_a_square_and_a_rectangle() -> None:
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=np.float32)
    assert mean_side(square) == pytest.approx(10.0)
    rectangle = np.array([[5, 5], [25, 5], [25, 15], [5, 15]], dtype=np.float64)
    assert mean_side(rectangle) == pytest.approx(15.0)  # (20 + 10 + 20 + 10) / 4


def test_plausible_intrinsics_pass() -> None:
    check_intrinsics(700.0, 700.0, 640.0, 360.0, width=1280, height=720)
    check_intrinsics(500.0, 500.0, 319.5, 239.5)


@pytest.mark.parametrize(
    ("intrinsics", "size", "match"),
    [
        ((0.0, 500.0, 320.0, 240.0), (640, 480), "fx"),
        ((500.0, 1e9, 320.0, 240.0), (640, 480), "fy"),
        ((500.0, 100.0, 320.0, 240.0), (640, 480), "factor"),
        ((500.0, 500.0, 0.0, 0.0), (640, 480), "principal point"),
        ((500.0, 500.0, 700.0, 240.0), (640, 480), "principal point"),
        ((500.0, 500.0, 320.0, 240.0), (200, 100), "principal point"),
        ((math.nan, 500.0, 320.0, 240.0), (640, 480), "finite"),
        ((500.0, 500.0, 320.0, math.inf), (0, 0), "finite"),
    ],
)
def test_implausible_intrinsics_are_refused(
    intrinsics: tuple[float, float, float, float], size: tuple[int, int], match: str
) -> None:
    with pytest.raises(IntrinsicsError, match=match) as info:
        check_intrinsics(*intrinsics, width=size[0], height=size[1])
    assert info.value.reason == "bad_intrinsics"
