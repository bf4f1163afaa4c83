"""Camera intrinsics from a sensor_msgs/msg/CameraInfo CDR sample."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from zenoh_perception.errors import CameraInfoError, CameraInfoTooLargeError
from zenoh_perception.tags.geometry import check_intrinsics
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.wire.messages import CAMERA_INFO_TYPE, deserialize

#: Largest CameraInfo sample accepted: its fixed matrices take about 300 bytes; the rest is a
#: frame id and a distortion model name and vector, a few hundred bytes more.
MAX_CAMERA_INFO_BYTES: Final = 64 * 1024


@dataclass(frozen=True, slots=True)
class CameraInfo:
    """The intrinsics of a CameraInfo, and the image size they are for."""

    intrinsics: Intrinsics
    width: int
    height: int


def check_camera_info_size(size: int) -> None:
    """Refuse a CameraInfo payload of ``size`` bytes before it is copied.

    Raises:
        CameraInfoTooLargeError: ``size`` exceeds :data:`MAX_CAMERA_INFO_BYTES`.

    """
    if size > MAX_CAMERA_INFO_BYTES:
        text = f"CameraInfo of {size} bytes, over the {MAX_CAMERA_INFO_BYTES} accepted"
        raise CameraInfoTooLargeError(text)


def decode_camera_info(payload: bytes | memoryview) -> CameraInfo:
    """Intrinsics (K matrix) and image size from a sensor_msgs/msg/CameraInfo CDR sample.

    Raises:
        CameraInfoTooLargeError: over :data:`MAX_CAMERA_INFO_BYTES`.
        CameraInfoError: not a CameraInfo sample, or a K matrix that is not 3 x 3.
        IntrinsicsError: intrinsics outside plausible bounds for the sample's image size
            (see :func:`~zenoh_perception.tags.geometry.check_intrinsics`).

    """
    check_camera_info_size(len(payload))
    msg = deserialize(payload, CAMERA_INFO_TYPE, CameraInfoError)
    k = np.asarray(msg.k, dtype=np.float64).reshape(-1)
    if k.size != 9:
        text = f"CameraInfo K has {k.size} values, not 9"
        raise CameraInfoError(text)
    fx, fy, cx, cy = float(k[0]), float(k[4]), float(k[2]), float(k[5])
    width, height = int(msg.width), int(msg.height)
    check_intrinsics(fx, fy, cx, cy, width=width, height=height)
    return CameraInfo(Intrinsics(fx, fy, cx, cy), width, height)
