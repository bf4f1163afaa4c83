"""Tag poses as tf2_msgs/msg/TFMessage: byte for byte the layout of geometry_msgs'
TransformStamped, read back by rosbags with the pose the service found."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import pytest

from tests.wire.cdr import CdrWriter
from zenoh_perception.settings import Settings
from zenoh_perception.tags.pose import quaternion_from_rvec
from zenoh_perception.tags.selection import TagObservation
from zenoh_perception.wire.messages import TF_MESSAGE_TYPE, TYPESTORE
from zenoh_perception.wire.tf import TF_TOPIC, encode_tf

SQUARE = ((0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0))


def _tag(tag_id: int, pose: bool = True) -> TagObservation:
    rvec = (0.0, 0.0, math.pi / 2) if pose else None
    tvec = (0.1, -0.2, 1.5) if pose else None
    return TagObservation(tag_id, 5.0, 5.0, 0.1, SQUARE, 100.0, 1.5 if pose else None, rvec, tvec)


def test_the_topic_is_tf() -> None:
    assert (TF_TOPIC.key_setting, TF_TOPIC.ros_type) == ("tf_key", "tf2_msgs/msg/TFMessage")
    assert Settings().outputs.tf_key == "tf"  # the ROS topic /tf, through the bridge


def test_the_bytes_follow_transform_stamped_field_by_field() -> None:
    expected = CdrWriter().put("I", 1).header(3, 4, "zed_left").string("tag_9")
    expected.put("3d", 0.1, -0.2, 1.5).put("4d", *quaternion_from_rvec((0.0, 0.0, math.pi / 2)))
    payload = encode_tf([_tag(9)], prefix="tag_", stamp_ns=3_000_000_004, frame_id="zed_left")
    assert payload is not None
    assert bytes(payload) == expected.bytes()


def test_rosbags_reads_back_one_transform_per_tag_with_a_pose() -> None:
    payload = encode_tf(
        [_tag(9), _tag(4, pose=False), _tag(2)], prefix="fid/", stamp_ns=7, frame_id="cam"
    )
    assert payload is not None
    msg: Any = TYPESTORE.deserialize_cdr(bytes(payload), TF_MESSAGE_TYPE)
    assert [t.child_frame_id for t in msg.transforms] == ["fid/9", "fid/2"]
    first = msg.transforms[0]
    assert (first.header.frame_id, first.header.stamp.sec, first.header.stamp.nanosec) == (
        "cam",
        0,
        7,
    )
    t, r = first.transform.translation, first.transform.rotation
    assert (t.x, t.y, t.z) == (0.1, -0.2, 1.5)
    assert (r.x, r.y, r.z, r.w) == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))


def test_no_message_when_no_tag_has_a_pose() -> None:
    assert encode_tf([_tag(1, pose=False)], prefix="tag_", stamp_ns=0, frame_id="c") is None
    assert encode_tf([], prefix="tag_", stamp_ns=0, frame_id="c") is None


def test_an_ambiguous_pose_is_not_published() -> None:
    flippable = replace(_tag(4), ambiguous=True, pose_errors=(0.05, 0.06))
    payload = encode_tf([_tag(9), flippable], prefix="tag_", stamp_ns=7, frame_id="cam")
    assert payload is not None
    msg: Any = TYPESTORE.deserialize_cdr(bytes(payload), TF_MESSAGE_TYPE)
    assert [t.child_frame_id for t in msg.transforms] == ["tag_9"]
    assert encode_tf([flippable], prefix="tag_", stamp_ns=7, frame_id="cam") is None
