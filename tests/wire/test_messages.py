"""The wire's ROS 2 types: the StarterProjectTag definition, the typestore, stamps and headers,
and the strict decoders every payload goes through."""

from __future__ import annotations

import dataclasses
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import REPO
from zenoh_perception.errors import AttachmentError, CameraInfoError, MessageDecodeError
from zenoh_perception.wire.messages import (
    CAMERA_INFO_TYPE,
    COMPRESSED_IMAGE_TYPE,
    DEFAULT_ROS_PACKAGE,
    IMAGE_TYPE,
    STARTER_PROJECT_TAG_MSG,
    TIME_MAX_NS,
    TIME_MIN_NS,
    TYPESTORE,
    clamp_stamp_ns,
    deserialize,
    header,
    make_typestore,
    stamp_ns_of,
    tag_type_name,
    unpack_msgpack_map,
)


def test_schema_msg_file_is_the_registered_definition() -> None:
    text = (REPO / "schemas" / "StarterProjectTag.msg").read_text(encoding="utf-8")
    assert text == STARTER_PROJECT_TAG_MSG
    fields = [line.split()[1] for line in text.splitlines() if line.strip()]
    assert fields == ["tag_id", "x_tag_center_pixel", "y_tag_center_pixel", "closeness_metric"]


def test_header_clamps_stamps_to_what_ros_time_holds() -> None:
    assert header(2**62, "f").stamp.sec == 2**31 - 1
    assert header(2**62, "f").stamp.nanosec == 999_999_999
    assert header(-(2**62), "f").stamp.sec == -(2**31)
    assert header(-5, "f").stamp.sec == -1
    assert header(-5, "f").stamp.nanosec == 999_999_995


@given(st.integers(min_value=-(2**70), max_value=2**70))
def test_a_header_holds_the_stamp_clamped_to_ros_time(stamp_ns: int) -> None:
    clamped = clamp_stamp_ns(stamp_ns)
    assert TIME_MIN_NS <= clamped <= TIME_MAX_NS
    assert clamped == stamp_ns or not TIME_MIN_NS <= stamp_ns <= TIME_MAX_NS
    msg = header(stamp_ns, "cam")
    assert 0 <= msg.stamp.nanosec < 1_000_000_000
    assert stamp_ns_of(msg) == clamped
    assert msg.frame_id == "cam"


@given(st.integers(min_value=TIME_MIN_NS, max_value=TIME_MAX_NS), st.text(max_size=20))
def test_a_header_survives_cdr_unchanged(stamp_ns: int, frame_id: str) -> None:
    types = TYPESTORE.types
    message = types["sensor_msgs/msg/CompressedImage"](
        header=header(stamp_ns, frame_id), format="jpeg", data=np.zeros(3, dtype=np.uint8)
    )
    raw = bytes(TYPESTORE.serialize_cdr(message, COMPRESSED_IMAGE_TYPE))
    back = deserialize(raw, COMPRESSED_IMAGE_TYPE, MessageDecodeError)
    assert (stamp_ns_of(back.header), back.header.frame_id) == (stamp_ns, frame_id)


def test_the_tag_type_is_registered_under_its_package() -> None:
    store = make_typestore("my_robot_msgs")
    assert tag_type_name("my_robot_msgs") == "my_robot_msgs/msg/StarterProjectTag"
    tag_class: Any = store.types["my_robot_msgs/msg/StarterProjectTag"]
    fields = dataclasses.fields(tag_class)
    assert [f.name for f in fields][:4] == [
        "tag_id",
        "x_tag_center_pixel",
        "y_tag_center_pixel",
        "closeness_metric",
    ]
    assert tag_type_name() == f"{DEFAULT_ROS_PACKAGE}/msg/StarterProjectTag"
    assert tag_type_name() in TYPESTORE.types
    for standard in (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE, CAMERA_INFO_TYPE):
        assert standard in TYPESTORE.types


def _string_cdr(text: str) -> bytes:
    msg = TYPESTORE.types["std_msgs/msg/String"](data=text)
    return bytes(TYPESTORE.serialize_cdr(msg, "std_msgs/msg/String"))


def test_deserialize_reads_one_whole_sample() -> None:
    raw = _string_cdr("hello")
    assert deserialize(raw, "std_msgs/msg/String", MessageDecodeError).data == "hello"
    assert deserialize(memoryview(raw), "std_msgs/msg/String", MessageDecodeError).data == "hello"


@pytest.mark.parametrize(
    "payload",
    [b"", b"\x00\x01", b"\x00\x01\x00\x00\xff\xff\xff\x7f", _string_cdr("hello") + bytes(8)],
    ids=["empty", "header-only", "length-beyond-the-end", "trailing-bytes"],
)
def test_deserialize_raises_the_given_error_for_anything_else(payload: bytes) -> None:
    with pytest.raises(CameraInfoError) as info:
        deserialize(payload, "std_msgs/msg/String", CameraInfoError)
    assert info.value.reason == "bad_camera_info"


@given(st.binary(max_size=64))
def test_any_bytes_deserialize_or_raise_the_given_error(payload: bytes) -> None:
    try:
        msg = deserialize(payload, "std_msgs/msg/String", MessageDecodeError)
    except MessageDecodeError:
        return
    assert isinstance(msg.data, str)


def test_unpack_msgpack_map_gives_the_map_or_the_given_error() -> None:
    assert unpack_msgpack_map(msgpack.packb({"a": 1, 2: [3]}), AttachmentError, "x") == {
        "a": 1,
        2: [3],
    }
    with pytest.raises(AttachmentError, match="attachment is a msgpack list, not a map"):
        unpack_msgpack_map(msgpack.packb([1, 2]), AttachmentError, "attachment")
    with pytest.raises(AttachmentError, match="attachment is not msgpack"):
        unpack_msgpack_map(b"\xc1", AttachmentError, "attachment")


@given(st.binary(max_size=64))
def test_any_bytes_unpack_to_a_map_or_the_given_error(data: bytes) -> None:
    try:
        value = unpack_msgpack_map(data, AttachmentError, "attachment")
    except AttachmentError:
        return
    assert isinstance(value, dict)
