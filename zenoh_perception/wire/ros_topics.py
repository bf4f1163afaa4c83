"""Every ROS topic the service publishes or subscribes: one table, whatever the transport.

An entry names its ROS type, the setting that holds its Zenoh key in bridge mode (the key
*is* the ROS topic name, relative, as zenoh-bridge-ros2dds maps ``/tag`` to ``tag``) and the
QoS it advertises on an rmw_zenoh graph; a camera topic also names the input kinds
(:class:`~zenoh_perception.wire.input_kinds.InputKind`) read on its keys. The transport
(``service/ros_transport.py``) turns an entry into a plain key (``bridge``) or an rmw_zenoh
key with its liveliness token (``rmw_zenoh``); a new topic is one more entry here.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Final

from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.messages import (
    APRILTAG_DETECTION_ARRAY_TYPE,
    CAMERA_INFO_TYPE,
    COMPRESSED_IMAGE_TYPE,
    IMAGE_TYPE,
    TF_MESSAGE_TYPE,
    tag_type_name,
)
from zenoh_perception.wire.rmw_zenoh import DEFAULT_QOS, SENSOR_DATA_QOS, Qos


class Direction(Enum):
    PUBLISH = "publish"
    SUBSCRIBE = "subscribe"


@dataclass(frozen=True, slots=True)
class RosTopic:
    """One ROS topic of the service."""

    role: str  # how the service code names it
    ros_type: str  # e.g. sensor_msgs/msg/Image; "{package}" stands for ``ros_package``
    key_setting: str  # the Settings field holding the bridge key ('' there = topic off)
    direction: Direction
    qos: Qos
    #: Subscriptions: match every type hash of ``ros_type`` (distributions differ), not only
    #: the one rosbags computes.
    any_hash: bool = False
    #: A camera topic: the input kinds whose samples come on its keys.
    inputs: tuple[InputKind, ...] = ()

    def type_name(self, ros_package: str) -> str:
        return self.ros_type.format(package=ros_package)


ROS_TOPICS: Final = (
    RosTopic(
        "camera",
        IMAGE_TYPE,
        "input_key",
        Direction.SUBSCRIBE,
        SENSOR_DATA_QOS,
        any_hash=True,
        # raw frames are no ROS message: through the bridge they come on the same keys as
        # the Image CDR it forwards, told apart by their attachment
        inputs=(InputKind.RAW, InputKind.CDR),
    ),
    RosTopic(
        "compressed_camera",
        COMPRESSED_IMAGE_TYPE,
        "compressed_input_key",
        Direction.SUBSCRIBE,
        SENSOR_DATA_QOS,
        any_hash=True,
        inputs=(InputKind.COMPRESSED,),
    ),
    RosTopic(
        "camera_info",
        CAMERA_INFO_TYPE,
        "camera_info_key",
        Direction.SUBSCRIBE,
        SENSOR_DATA_QOS,
        any_hash=True,
    ),
    RosTopic("tag", tag_type_name("{package}"), "tag_key", Direction.PUBLISH, DEFAULT_QOS),
    RosTopic(
        "debug_image",
        COMPRESSED_IMAGE_TYPE,
        "debug_image_key",
        Direction.PUBLISH,
        SENSOR_DATA_QOS,
    ),
    RosTopic(
        "detections",
        APRILTAG_DETECTION_ARRAY_TYPE,
        "detections_key",
        Direction.PUBLISH,
        DEFAULT_QOS,
    ),
    RosTopic("tf", TF_MESSAGE_TYPE, "tf_key", Direction.PUBLISH, DEFAULT_QOS),
)


def ros_topic(role: str) -> RosTopic:
    """The entry of ``role``; KeyError when there is none."""
    for topic in ROS_TOPICS:
        if topic.role == role:
            return topic
    raise KeyError(role)


def input_role(kind: InputKind) -> str:
    """The role of the camera topic on whose keys input ``kind``'s samples come."""
    for topic in ROS_TOPICS:
        if kind in topic.inputs:
            return topic.role
    raise KeyError(kind)


#: The roles of the camera topics, each once.
INPUT_ROLES: Final = tuple(topic.role for topic in ROS_TOPICS if topic.inputs)
