"""ROS 2 message types used on the wire, registered in one rosbags typestore.

``StarterProjectTag`` is not a standard ROS type; its definition below must match
``schemas/StarterProjectTag.msg`` (a test checks that they are identical).
"""

from __future__ import annotations

import struct
from typing import Any, Final

import msgpack
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from zenoh_perception.errors import PerceptionError

#: The .msg definition of the tag message; field order is the wire order.
STARTER_PROJECT_TAG_MSG: Final = """\
int32 tag_id
float32 x_tag_center_pixel
float32 y_tag_center_pixel
float32 closeness_metric
"""

#: apriltag_msgs (github.com/christianrauch/apriltag_msgs, version 2.0.1, what apriltag_ros
#: publishes): the .msg definitions of its three types, by type name. Not in rosbags' stores.
APRILTAG_MSGS: Final = {
    "apriltag_msgs/msg/Point": "float64 x\nfloat64 y\n",
    "apriltag_msgs/msg/AprilTagDetection": """\
string family
int32 id
int32 hamming
float32 goodness
float32 decision_margin
apriltag_msgs/Point centre
apriltag_msgs/Point[4] corners
float64[9] homography
""",
    "apriltag_msgs/msg/AprilTagDetectionArray": """\
std_msgs/Header header
apriltag_msgs/AprilTagDetection[] detections
""",
}
APRILTAG_DETECTION_ARRAY_TYPE: Final = "apriltag_msgs/msg/AprilTagDetectionArray"
TF_MESSAGE_TYPE: Final = "tf2_msgs/msg/TFMessage"

DEFAULT_ROS_PACKAGE: Final = "mrover"
IMAGE_TYPE: Final = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE: Final = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE: Final = "sensor_msgs/msg/CameraInfo"


def tag_type_name(package: str = DEFAULT_ROS_PACKAGE) -> str:
    """The full ROS type name of the tag message in ``package``."""
    return f"{package}/msg/StarterProjectTag"


def make_typestore(package: str = DEFAULT_ROS_PACKAGE) -> Typestore:
    """A ROS 2 Jazzy typestore with StarterProjectTag registered under ``package``, and
    apriltag_msgs."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(STARTER_PROJECT_TAG_MSG, tag_type_name(package)))
    for name, text in APRILTAG_MSGS.items():
        store.register(get_types_from_msg(text, name))
    return store


#: Shared typestore for the standard types (Image, CompressedImage, CameraInfo, TFMessage),
#: apriltag_msgs and the tag
#: in the default package. The CDR bytes of the tag do not depend on the package name.
TYPESTORE: Final = make_typestore()


#: The range of builtin_interfaces/msg/Time (int32 seconds, nanoseconds below one second), in
#: nanoseconds since the epoch.
TIME_MIN_NS: Final = -(2**31) * 1_000_000_000
TIME_MAX_NS: Final = (2**31 - 1) * 1_000_000_000 + 999_999_999


def clamp_stamp_ns(stamp_ns: int) -> int:
    """``stamp_ns`` clamped to what builtin_interfaces/msg/Time can hold (its int32 seconds end
    in January 2038; a raw frame's stamp may lie beyond)."""
    return min(max(stamp_ns, TIME_MIN_NS), TIME_MAX_NS)


def header(stamp_ns: int, frame_id: str) -> Any:
    """A std_msgs/Header for ``stamp_ns`` (nanoseconds since the epoch, clamped to the range
    of builtin_interfaces/msg/Time) and ``frame_id``."""
    types = TYPESTORE.types
    stamp_ns = clamp_stamp_ns(stamp_ns)
    return types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
        ),
        frame_id=frame_id,
    )


def stamp_ns_of(msg_header: Any) -> int:
    """Nanoseconds since the epoch of a deserialised std_msgs/Header."""
    return int(msg_header.stamp.sec) * 1_000_000_000 + int(msg_header.stamp.nanosec)


def deserialize(
    payload: bytes | memoryview,
    typename: str,
    error: type[PerceptionError],
    store: Typestore = TYPESTORE,
) -> Any:
    """Deserialise one CDR sample (4-byte header included) of ``typename``.

    A memoryview (or bytes) payload gives zero-copy numpy views for primitive arrays. Every
    failure, including a sample longer than the message (rosbags checks that the decoder
    consumed the payload up to CDR's final alignment), is raised as ``error``.
    """
    view = payload if isinstance(payload, memoryview) else memoryview(payload)
    try:
        return store.deserialize_cdr(view, typename)
    except (SerdeError, struct.error, ValueError, IndexError, UnicodeDecodeError) as err:
        text = f"not a {typename} CDR sample: {err}"
        raise error(text) from err


def unpack_msgpack_map(
    data: bytes | memoryview, error: type[PerceptionError], what: str
) -> dict[Any, Any]:
    """Parse msgpack that must be a map; anything else is raised as ``error``.

    msgpack bounds every container and string by the input length, so this never allocates
    more than ``data`` holds.
    """
    try:
        value = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except (ValueError, msgpack.UnpackException, TypeError) as err:
        text = f"{what} is not msgpack: {err}"
        raise error(text) from err
    if not isinstance(value, dict):
        text = f"{what} is a msgpack {type(value).__name__}, not a map"
        raise error(text)
    return value
