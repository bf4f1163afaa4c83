"""Camera intrinsics from a sensor_msgs/msg/CameraInfo CDR sample."""

from __future__ import annotations

import numpy as np

from zenoh_perception.errors import CameraInfoError
from zenoh_perception.tags.geometry import check_intrinsics
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.wire.messages import CAMERA_INFO_TYPE, deserialize


def decode_camera_info(payload: bytes | memoryview) -> Intrinsics:
    """Intrinsics (K matrix) from a sensor_msgs/msg/CameraInfo CDR sample.

    Raises:
        CameraInfoError: not a CameraInfo sample, or a K matrix that is not 3 x 3.
        IntrinsicsError: intrinsics outside plausible bounds for the sample's image size
            (see :func:`~zenoh_perception.tags.geometry.check_intrinsics`).

    """
    msg = deserialize(payload, CAMERA_INFO_TYPE, CameraInfoError)
    k = np.asarray(msg.k, dtype=np.float64).reshape(-1)
    if k.size != 9:
        text = f"CameraInfo K has {k.size} values, not 9"
        raise CameraInfoError(text)
    fx, fy, cx, cy = float(k[0]), float(k[4]), float(k[2]), float(k[5])
    check_intrinsics(fx, fy, cx, cy, width=int(msg.width), height=int(msg.height))
    return Intrinsics(fx, fy, cx, cy)
