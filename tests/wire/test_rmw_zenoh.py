"""rmw_zenoh's formats, against ros2/rmw_zenoh's docs/design.md (its own examples) and the
type hashes ROS 2 itself ships."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from zenoh.ext import Int64, z_serialize

from zenoh_perception.errors import RmwZenohError
from zenoh_perception.wire.messages import TYPESTORE, make_typestore
from zenoh_perception.wire.rmw_zenoh import (
    ATTACHMENT_SIZE,
    DEFAULT_QOS,
    PUBLISHER,
    SENSOR_DATA_QOS,
    SUBSCRIPTION,
    Attachment,
    Durability,
    History,
    NodeInfo,
    Qos,
    Reliability,
    dds_type_name,
    decode_attachment,
    fully_qualified,
    gid_of,
    is_namespace,
    is_node_name,
    is_relative_topic,
    mangle,
    parse_token,
    topic_key,
    type_hash,
)

# RIHS01 type hashes as ROS 2 Jazzy's rosidl generated them: share/sensor_msgs/msg/<Type>.json
# ("type_hashes") in the PyPI wheel ros-sensor-msgs 5.3.6 (cp311 manylinux_2_28_x86_64, the
# build ros-jazzy-sensor-msgs 5.3.6 depends on); std_msgs/msg/String from rmw_zenoh's
# docs/design.md examples.
ROS2_TYPE_HASHES = {
    "sensor_msgs/msg/Image": (
        "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
    ),
    "sensor_msgs/msg/CompressedImage": (
        "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"
    ),
    "sensor_msgs/msg/CameraInfo": (
        "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275"
    ),
    "std_msgs/msg/String": (
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    ),
}
STRING = "std_msgs/msg/String"
STRING_HASH = ROS2_TYPE_HASHES[STRING]


@pytest.mark.parametrize("ros_type", sorted(ROS2_TYPE_HASHES))
def test_type_hashes_computed_by_rosbags_equal_ros2s_own(ros_type: str) -> None:
    assert type_hash(TYPESTORE, ros_type) == ROS2_TYPE_HASHES[ros_type]


def test_the_tag_type_hash_does_not_depend_on_the_package_but_on_the_definition() -> None:
    tag = type_hash(make_typestore("mrover"), "mrover/msg/StarterProjectTag")
    other = type_hash(make_typestore("rover_msgs"), "rover_msgs/msg/StarterProjectTag")
    assert tag.startswith("RIHS01_")
    assert len(tag) == len("RIHS01_") + 64
    # the type name is part of what is hashed (REP 2016): another package, another hash
    assert tag != other


def test_dds_type_names() -> None:
    assert dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert dds_type_name("mrover/msg/StarterProjectTag") == "mrover::msg::dds_::StarterProjectTag_"


def test_data_keys_are_the_design_documents_examples() -> None:
    assert topic_key(0, "/chatter", STRING, STRING_HASH) == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    assert topic_key(0, fully_qualified("/robot1", "chatter"), STRING, STRING_HASH) == (
        "0/robot1/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )


def test_the_services_tag_key() -> None:
    tag_hash = type_hash(make_typestore("mrover"), "mrover/msg/StarterProjectTag")
    key = topic_key(0, fully_qualified("", "tag"), "mrover/msg/StarterProjectTag", tag_hash)
    assert key == f"0/tag/mrover::msg::dds_::StarterProjectTag_/{tag_hash}"
    image = topic_key(7, fully_qualified("/rover", "zed/left/image"), "sensor_msgs/msg/Image", "*")
    assert image == "7/rover/zed/left/image/sensor_msgs::msg::dds_::Image_/*"


def test_fully_qualified_names() -> None:
    assert fully_qualified("", "tag") == "/tag"
    assert fully_qualified("/", "tag") == "/tag"
    assert fully_qualified("/rover", "zed/left/image") == "/rover/zed/left/image"
    assert fully_qualified("/rover", "/tag") == "/tag"


def test_node_and_entity_tokens_are_the_design_documents_examples() -> None:
    listener = NodeInfo(2, "aac3178e146ba6f1fc6e6a4085e77f21", "listener")
    assert (
        listener.node_token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    )
    assert listener.entity_token(
        10, SUBSCRIPTION, "/chatter", STRING, hash_=STRING_HASH, qos=Qos(depth=10)
    ) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,"
    )
    talker = NodeInfo(2, "8b20917502ee955ac4476e0266340d5c", "talker")
    assert talker.entity_token(
        10, PUBLISHER, "/chatter", STRING, hash_=STRING_HASH, qos=Qos(depth=7)
    ) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
    )


def test_namespaced_node_tokens_mangle_every_slash() -> None:
    node = NodeInfo(0, "ab", "zenoh_perception", namespace="/rover/left", enclave="/sros")
    assert node.node_token() == "@ros2_lv/0/ab/0/0/NN/%sros/%rover%left/zenoh_perception"
    token = node.entity_token(
        3, PUBLISHER, "/rover/left/tag", STRING, hash_=STRING_HASH, qos=DEFAULT_QOS
    )
    assert "/MP/%sros/%rover%left/zenoh_perception/%rover%left%tag/" in token
    assert mangle("") == mangle("/") == "%"


def test_qos_strings_leave_rmw_zenohs_defaults_empty() -> None:
    assert Qos().keyexpr() == "::,:,:,:,,"  # reliable, volatile, keep last 42
    assert DEFAULT_QOS.keyexpr() == "::,10:,:,:,,"
    assert SENSOR_DATA_QOS.keyexpr() == "2::,5:,:,:,,"
    latched = Qos(Reliability.BEST_EFFORT, Durability.TRANSIENT_LOCAL, History.KEEP_ALL, 1)
    assert latched.keyexpr() == "2:1:2,1:,:,:,,"


def test_tokens_parse_back() -> None:
    node = NodeInfo(0, "0123abcd", "zenoh_perception", namespace="/rover")
    token = node.entity_token(
        4, SUBSCRIPTION, "/rover/zed/left/image", "sensor_msgs/msg/Image",
        hash_=ROS2_TYPE_HASHES["sensor_msgs/msg/Image"], qos=SENSOR_DATA_QOS,
    )  # fmt: skip
    parsed = parse_token(token)
    assert (parsed.kind, parsed.entity_id, parsed.node_name) == ("MS", "4", "zenoh_perception")
    assert (parsed.namespace, parsed.topic) == ("/rover", "/rover/zed/left/image")
    assert parsed.dds_type == "sensor_msgs::msg::dds_::Image_"
    assert parsed.type_hash == ROS2_TYPE_HASHES["sensor_msgs/msg/Image"]
    assert parsed.qos == "2::,5:,:,:,,"
    assert parse_token(node.node_token()).kind == "NN"
    for bad in ("@ros2_lv/0/a/0/0/NN/%/%", "perception/alive/x", "@ros2_lv/x/a/0/0/NN/%/%/n"):
        with pytest.raises(RmwZenohError):
            parse_token(bad)


def test_gid_is_xxh3_128_low_then_high_64_bits_little_endian() -> None:
    # XXH3_128bits("") = 0x99aa06d3014798d8_6001c324468d497f (xxHash's published vector)
    assert gid_of("") == bytes.fromhex("7f498d4624c30160d8984701d306aa99")
    assert gid_of("@ros2_lv/0/a/0/1/MP/%/%/n/%t/T/H/::,:,:,:,,") != gid_of("@ros2_lv/0/a/0/2")


def test_attachment_bytes_follow_the_design_document() -> None:
    gid = bytes(range(16))
    stamp = 0x0102030405060708
    encoded = Attachment(1, stamp, gid).encode()
    # 8 bytes sequence number LE, 8 bytes timestamp LE, 1 byte GID length (16), 16 bytes GID
    assert encoded == (
        bytes.fromhex("0100000000000000") + bytes.fromhex("0807060504030201") + b"\x10" + gid
    )
    assert len(encoded) == ATTACHMENT_SIZE == 33
    # and what rmw_zenoh's serializer (zenoh-ext, here zenoh-python's) makes of the same fields
    assert encoded == z_serialize((Int64(1), Int64(stamp), gid)).to_bytes()


@given(
    seq=st.integers(-(2**63), 2**63 - 1),
    stamp=st.integers(-(2**63), 2**63 - 1),
    gid=st.binary(min_size=16, max_size=16),
)
def test_attachments_round_trip(seq: int, stamp: int, gid: bytes) -> None:
    attachment = Attachment(seq, stamp, gid)
    assert decode_attachment(attachment.encode()) == attachment


@given(st.binary(max_size=64))
def test_malformed_attachments_are_typed_errors(data: bytes) -> None:
    try:
        decoded = decode_attachment(data)
    except RmwZenohError:
        return
    assert len(data) == 33
    assert data[16] == 16
    assert decoded.gid == data[17:]


def test_a_gid_length_other_than_16_is_refused() -> None:
    data = bytearray(Attachment(1, 2, bytes(16)).encode())
    data[16] = 15
    with pytest.raises(RmwZenohError, match="GID of 15 bytes"):
        decode_attachment(bytes(data))


@pytest.mark.parametrize(
    ("name", "node", "namespace", "topic"),
    [
        ("zenoh_perception", True, False, True),
        ("_private", True, False, True),
        ("1camera", False, False, False),
        ("a__b", False, False, False),
        ("has-dash", False, False, False),
        ("/rover", False, True, False),
        ("/rover/left", False, True, False),
        ("/", False, True, False),
        ("", False, True, False),
        ("/rover/", False, False, False),
        ("zed/left/image", False, False, True),
        ("zed/*/image", False, False, False),
        ("zed//image", False, False, False),
    ],
)
def test_ros_names(name: str, node: bool, namespace: bool, topic: bool) -> None:
    assert is_node_name(name) is node
    assert is_namespace(name) is namespace
    assert is_relative_topic(name) is topic
