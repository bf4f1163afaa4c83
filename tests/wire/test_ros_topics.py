"""The table of the service's ROS topics."""

from __future__ import annotations

import pytest

from zenoh_perception.settings import FLAT, Settings
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, make_typestore
from zenoh_perception.wire.ros_topics import (
    INPUT_ROLES,
    ROS_TOPICS,
    Direction,
    input_role,
    ros_topic,
)


def test_every_entry_names_a_key_setting_and_a_type_rosbags_knows() -> None:
    keys = Settings().topic_keys()  # what the transport reads each topic's key from
    assert set(keys) == {t.key_setting for t in ROS_TOPICS} and set(keys) <= set(FLAT)
    store = make_typestore("mrover")
    for topic in ROS_TOPICS:
        assert topic.type_name("mrover") in store.types
    assert len({t.role for t in ROS_TOPICS}) == len(ROS_TOPICS)


def test_the_services_topics() -> None:
    assert ros_topic("tag").type_name("rover_msgs") == "rover_msgs/msg/StarterProjectTag"
    assert ros_topic("tag").direction is Direction.PUBLISH
    assert ros_topic("debug_image").type_name("x") == "sensor_msgs/msg/CompressedImage"
    camera = ros_topic("camera")
    assert (camera.direction, camera.any_hash) == (Direction.SUBSCRIBE, True)
    with pytest.raises(KeyError):
        ros_topic("nothing")


def test_each_input_kind_is_read_on_one_camera_topic_of_its_type() -> None:
    kinds = [kind for topic in ROS_TOPICS for kind in topic.inputs]
    assert sorted(kinds) == sorted(InputKind)
    # raw frames share the Image topic's keys (through the bridge, beside its Image CDR)
    assert ros_topic(input_role(InputKind.RAW)) is ros_topic(input_role(InputKind.CDR))
    assert ros_topic(input_role(InputKind.CDR)).ros_type == IMAGE_TYPE
    assert ros_topic(input_role(InputKind.COMPRESSED)).ros_type == COMPRESSED_IMAGE_TYPE
    assert INPUT_ROLES == ("camera", "compressed_camera")
    for role in INPUT_ROLES:
        assert ros_topic(role).direction is Direction.SUBSCRIBE
