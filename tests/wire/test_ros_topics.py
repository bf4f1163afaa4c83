"""The table of the service's ROS topics."""

from __future__ import annotations

import pytest

from zenoh_perception.settings import FLAT, Settings
from zenoh_perception.wire.messages import make_typestore
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction, ros_topic


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
