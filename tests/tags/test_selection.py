"""The selection policies: which tag answers a frame, under each policy and metric."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

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
