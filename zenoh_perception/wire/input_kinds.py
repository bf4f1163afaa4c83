"""The kinds of frame input: one name each, used by the service's inputs, the ROS topics
table (:mod:`~zenoh_perception.wire.ros_topics`) and the record's ``source``. No OpenCV, so
the settings may import it."""

from __future__ import annotations

from enum import StrEnum


class InputKind(StrEnum):
    """What a frame input's samples carry, named as a frame's record names its source: raw
    pixels with a msgpack attachment (a sample without one is read as sensor_msgs/Image CDR),
    sensor_msgs/Image CDR (the camera topic on an rmw_zenoh graph), or
    sensor_msgs/CompressedImage CDR."""

    RAW = "raw"
    CDR = "cdr"
    COMPRESSED = "compressed"
