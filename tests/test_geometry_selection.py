"""Tag geometry, the closeness metric and the selection policies."""

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
from zenoh_perception.tags.selection import (
    NO_TAG,
    Metric,
    Policy,
    TagObservation,
    select_tag,
    selected_message,
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


def _tag(
    tag_id: int, x: float, y: float, closeness: float, metric: Metric = Metric.AREA
) -> TagObservation:
    corners = tuple((float(a), float(b)) for a, b in _square(x - 5, y - 5, 10))
    return TagObservation(tag_id, x, y, closeness, corners, 100.0, metric=metric)


def test_no_detection_selects_the_dummy() -> None:
    assert select_tag([], 640, 480) is None
    assert selected_message([], 640, 480) == NO_TAG
    assert (NO_TAG.tag_id, NO_TAG.x_tag_center_pixel, NO_TAG.closeness_metric) == (-1, 0.0, 0.0)


def test_closest_policy_picks_lowest_closeness() -> None:
    tags = [_tag(1, 320, 240, 0.9), _tag(2, 10, 10, 0.4), _tag(3, 600, 400, 0.7)]
    assert selected_message(tags, 640, 480).tag_id == 2


def test_closest_ties_go_to_the_centre_then_the_lower_id() -> None:
    tags = [_tag(5, 10, 10, 0.5), _tag(4, 300, 240, 0.5), _tag(9, 325, 240, 0.5)]
    assert selected_message(tags, 640, 480).tag_id == 9
    twins = [_tag(8, 300, 240, 0.5), _tag(6, 340, 240, 0.5)]  # equally far from the centre
    assert selected_message(twins, 640, 480).tag_id == 6


def test_center_policy_picks_nearest_the_image_centre() -> None:
    tags = [_tag(1, 320, 250, 0.9), _tag(2, 10, 10, 0.1)]
    assert selected_message(tags, 640, 480, Policy.CENTER).tag_id == 1


@given(
    st.lists(
        st.tuples(
            st.integers(min_value=0, max_value=49),
            st.floats(min_value=0, max_value=640),
            st.floats(min_value=0, max_value=480),
            st.floats(min_value=0, max_value=1),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_selection_is_the_minimum_and_order_independent(
    raw: list[tuple[int, float, float, float]],
) -> None:
    tags = [_tag(*fields) for fields in raw]
    chosen = selected_message(tags, 640, 480)
    assert chosen.closeness_metric == min(t.closeness for t in tags)
    assert selected_message(list(reversed(tags)), 640, 480) == chosen


def test_mean_side_of_a_square_and_a_rectangle() -> None:
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=np.float32)
    assert mean_side(square) == pytest.approx(10.0)
    rectangle = np.array([[5, 5], [25, 5], [25, 15], [5, 15]], dtype=np.float64)
    assert mean_side(rectangle) == pytest.approx(15.0)  # (20 + 10 + 20 + 10) / 4


def test_tags_without_a_distance_rank_after_every_tag_with_one() -> None:
    """Under metric=distance, an area closeness (no pose) is not comparable to a distance."""
    far_with_pose = _tag(1, 100, 100, 0.9, Metric.DISTANCE)
    near_with_pose = _tag(2, 500, 400, 0.6, Metric.DISTANCE)
    big_without_pose = _tag(3, 320, 240, 0.1, Metric.AREA)
    tags = [big_without_pose, far_with_pose, near_with_pose]
    assert selected_message(tags, 640, 480).tag_id == 2
    assert selected_message([big_without_pose, far_with_pose], 640, 480).tag_id == 1
    assert selected_message([big_without_pose], 640, 480).tag_id == 3
    # center: the centre decides; the metric only breaks a tie of the centre distance.
    assert selected_message(tags, 640, 480, Policy.CENTER).tag_id == 3
    twins = [_tag(4, 300, 240, 0.1, Metric.AREA), _tag(5, 340, 240, 0.9, Metric.DISTANCE)]
    assert selected_message(twins, 640, 480, Policy.CENTER).tag_id == 5


@given(
    st.lists(
        st.tuples(
            st.integers(min_value=0, max_value=49),
            st.floats(min_value=0, max_value=640),
            st.floats(min_value=0, max_value=480),
            st.floats(min_value=0, max_value=1),
            st.sampled_from(list(Metric)),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_closest_picks_the_lowest_distance_when_any_tag_has_one(
    raw: list[tuple[int, float, float, float, Metric]],
) -> None:
    tags = [_tag(*fields) for fields in raw]
    chosen = select_tag(tags, 640, 480)
    assert chosen is not None
    ranked = [t for t in tags if t.metric == Metric.DISTANCE] or tags
    assert chosen in ranked
    assert chosen.closeness == min(t.closeness for t in ranked)


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
