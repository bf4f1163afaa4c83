"""Tag poses as tf2_msgs/msg/TFMessage CDR: what apriltag_ros and aruco_ros publish on /tf.

One geometry_msgs/msg/TransformStamped per tag with a pose: parent the frame's ``frame_id``
(the camera's optical frame: x right, y down, z forward, OpenCV's axes), child
``<prefix><id>``, translation the pose's tvec in metres, rotation its rvec as a quaternion. The
tag's own axes are OpenCV's ArUco axes (:mod:`zenoh_perception.tags.pose`'s object points):
origin the marker's centre, x towards its right edge, y towards its top edge, z out of its
face (towards a camera that sees it). A pose marked ambiguous (it may be flipped, see
:mod:`zenoh_perception.tags.pose`) is not published: a tf consumer has no field to be told.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

from zenoh_perception.tags.pose import quaternion_from_rvec
from zenoh_perception.tags.selection import TagObservation
from zenoh_perception.wire.messages import TF_MESSAGE_TYPE, TYPESTORE, header
from zenoh_perception.wire.ros_topics import ros_topic

#: The output: the ROS topic of ``tf_key``'s default and its type.
TF_TOPIC: Final = ros_topic("tf")


def encode_tf(
    tags: Sequence[TagObservation], *, prefix: str, stamp_ns: int, frame_id: str
) -> memoryview | None:
    """TFMessage CDR with the transform of every tag that has a pose not marked ambiguous;
    None when none has."""
    types = TYPESTORE.types
    transforms = []
    for tag in tags:
        if tag.rvec is None or tag.tvec is None or tag.ambiguous:
            continue
        x, y, z, w = quaternion_from_rvec(tag.rvec)
        tx, ty, tz = (float(v) for v in tag.tvec)
        transforms.append(
            types["geometry_msgs/msg/TransformStamped"](
                header=header(stamp_ns, frame_id),
                child_frame_id=f"{prefix}{tag.tag_id}",
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](x=tx, y=ty, z=tz),
                    rotation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
                ),
            )
        )
    if not transforms:
        return None
    message = types[TF_MESSAGE_TYPE](transforms=transforms)
    raw: memoryview = TYPESTORE.serialize_cdr(message, TF_MESSAGE_TYPE)
    return raw
