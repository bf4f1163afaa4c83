"""The table of the service's ROS topics."""

from __future__ import annotations

from dataclasses import fields

import pytest

from zenoh_perception.settings import Settings
from zenoh_perception.wire.messages import make_typestore
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction, ros_topic


def test_every_entry_names_a_key_setting_and_a_type_rosbags_knows() -> None:
    names = {f.name for f in fields(Settings)}
    store = make_typestore("mrover")
    for topic in ROS_TOPICS:
        assert topic.key_setting in names
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
