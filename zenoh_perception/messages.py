"""ROS 2 message types used on the wire, registered in one rosbags typestore.

``StarterProjectTag`` is not a standard ROS type; its definition below must match
``schemas/StarterProjectTag.msg`` (a test checks that they are identical).
"""

from __future__ import annotations

from typing import Final

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

#: The .msg definition of the tag message; field order is the wire order.
STARTER_PROJECT_TAG_MSG: Final = """\
int32 tag_id
float32 x_tag_center_pixel
float32 y_tag_center_pixel
float32 closeness_metric
"""

DEFAULT_ROS_PACKAGE: Final = "mrover"
IMAGE_TYPE: Final = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE_TYPE: Final = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE: Final = "sensor_msgs/msg/CameraInfo"


def tag_type_name(package: str = DEFAULT_ROS_PACKAGE) -> str:
    """The full ROS type name of the tag message in ``package``."""
    return f"{package}/msg/StarterProjectTag"


def make_typestore(package: str = DEFAULT_ROS_PACKAGE) -> Typestore:
    """A ROS 2 Jazzy typestore with StarterProjectTag registered under ``package``."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(STARTER_PROJECT_TAG_MSG, tag_type_name(package)))
    return store


#: Shared typestore for the standard types (Image, CompressedImage, CameraInfo) and the tag
#: in the default package. The CDR bytes of the tag do not depend on the package name.
TYPESTORE: Final = make_typestore()
