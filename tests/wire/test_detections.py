"""Every detection as apriltag_msgs/msg/AprilTagDetectionArray: byte for byte the layout of
its .msg files, read back by rosbags with the values the service found."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.wire.cdr import CdrWriter
from zenoh_perception.settings import Settings
from zenoh_perception.tags.selection import TagObservation
from zenoh_perception.wire.detections import DETECTIONS_TOPIC, encode_detections, homography
from zenoh_perception.wire.messages import APRILTAG_DETECTION_ARRAY_TYPE, TYPESTORE

CORNERS = ((100.0, 50.0), (180.0, 60.0), (170.0, 140.0), (90.0, 130.0))


def _tag(tag_id: int, corners: tuple[tuple[float, float], ...] = CORNERS) -> TagObservation:
    xs, ys = zip(*corners, strict=True)
    return TagObservation(tag_id, sum(xs) / 4, sum(ys) / 4, 0.4, corners, 6400.0)


def _decode(payload: memoryview | bytes) -> Any:
    return TYPESTORE.deserialize_cdr(bytes(payload), APRILTAG_DETECTION_ARRAY_TYPE)


def test_the_topic_is_apriltag_ros_type_on_its_own_key() -> None:
    assert Settings().outputs.detections_key == "perception/detections"  # /perception/detections
    assert DETECTIONS_TOPIC.ros_type == "apriltag_msgs/msg/AprilTagDetectionArray"
    assert DETECTIONS_TOPIC.key_setting == "detections_key"


def test_the_bytes_follow_the_msg_definitions_field_by_field() -> None:
    tag = _tag(7)
    h = homography(tag.corners)
    expected = CdrWriter().header(12, 345, "zed_left").put("I", 1)
    expected.string("DICT_4X4_50").put("i", 7).put("i", 0).put("f", 0.0).put("f", 0.0)
    expected.put("d", tag.x).put("d", tag.y)
    for x, y in CORNERS:
        expected.put("d", x).put("d", y)
    expected.put("9d", *h)
    payload = encode_detections(
        [tag], family="DICT_4X4_50", stamp_ns=12_000_000_345, frame_id="zed_left"
    )
    assert bytes(payload) == expected.bytes()


def test_rosbags_reads_back_every_detection_with_the_frames_header() -> None:
    tags = [_tag(7), _tag(3, tuple((x + 300, y) for x, y in CORNERS))]
    msg = _decode(
        encode_detections(tags, family="DICT_5X5_100", stamp_ns=1_700_000_000_500, frame_id="cam")
    )
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1700, 500)
    assert msg.header.frame_id == "cam"
    assert [d.id for d in msg.detections] == [7, 3]
    assert {d.family for d in msg.detections} == {"DICT_5X5_100"}
    second = msg.detections[1]
    assert (second.centre.x, second.centre.y) == (tags[1].x, tags[1].y)
    assert [(c.x, c.y) for c in second.corners] == list(tags[1].corners)
    assert (second.hamming, second.goodness, second.decision_margin) == (0, 0.0, 0.0)


def test_a_frame_without_tags_is_an_empty_array() -> None:
    msg = _decode(encode_detections([], family="DICT_4X4_50", stamp_ns=0, frame_id="cam"))
    assert list(msg.detections) == []


def _apply(h: np.ndarray, x: float, y: float) -> tuple[float, float]:
    u, v, w = h.reshape(3, 3) @ np.array([x, y, 1.0])
    return u / w, v / w


def test_the_homography_maps_apriltags_square_onto_the_corners_in_order() -> None:
    h = homography(CORNERS)
    assert h[8] == pytest.approx(1.0)
    for (x, y), corner in zip([(-1, -1), (1, -1), (1, 1), (-1, 1)], CORNERS, strict=True):
        assert _apply(h, x, y) == pytest.approx(corner, abs=1e-3)
    # the square's centre goes to where the diagonals cross
    centre = _apply(h, 0.0, 0.0)
    diag = cv2.perspectiveTransform(np.array([[[0.0, 0.0]]]), h.reshape(3, 3))
    assert centre == pytest.approx(tuple(diag.reshape(2)), abs=1e-6)


def test_degenerate_corners_give_a_zero_homography() -> None:
    line = ((0.0, 0.0), (1.0, 1.0), (2.0, 2.0), (3.0, 3.0))
    assert not homography(line).any()
    assert not homography(((float("nan"), 0.0), *line[1:])).any()


_COORD = st.floats(-1e4, 1e4, allow_nan=False)


@given(st.lists(st.tuples(_COORD, _COORD), min_size=4, max_size=4))
def test_any_corners_encode_and_read_back(corners: list[tuple[float, float]]) -> None:
    tag = _tag(1, tuple(corners))
    msg = _decode(encode_detections([tag], family="F", stamp_ns=1, frame_id=""))
    assert [(c.x, c.y) for c in msg.detections[0].corners] == corners
    assert np.all(np.isfinite(msg.detections[0].homography))
