"""Camera intrinsics from sensor_msgs/msg/CameraInfo CDR: good, implausible and garbage samples."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.errors import CameraInfoError, IntrinsicsError
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.wire.camera_info import MAX_CAMERA_INFO_BYTES, decode_camera_info
from zenoh_perception.wire.messages import CAMERA_INFO_TYPE, TYPESTORE, header


def camera_info_cdr(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    *,
    width: int = 640,
    height: int = 480,
    little_endian: bool = True,
) -> bytes:
    """sensor_msgs/msg/CameraInfo CDR as a ROS 2 camera driver publishes it."""
    types = TYPESTORE.types
    info: Any = types[CAMERA_INFO_TYPE](
        header=header(1_700_000_000_000_000_000, "zed_left"),
        height=height,
        width=width,
        distortion_model="plumb_bob",
        d=np.array([0.1, -0.05, 0.0, 0.0, 0.0]),
        k=np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]),
        r=np.eye(3).reshape(-1),
        p=np.array([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )
    return bytes(TYPESTORE.serialize_cdr(info, CAMERA_INFO_TYPE, little_endian=little_endian))


@pytest.mark.parametrize("little_endian", [True, False], ids=["le", "be"])
def test_the_k_matrix_gives_the_intrinsics(little_endian: bool) -> None:
    hd720 = camera_info_cdr(
        700.5, 701.25, 640.0, 360.5, width=1280, height=720, little_endian=little_endian
    )
    assert decode_camera_info(hd720).intrinsics == Intrinsics(700.5, 701.25, 640.0, 360.5)
    vga = camera_info_cdr(500.0, 500.0, 319.5, 239.5, little_endian=little_endian)
    assert decode_camera_info(memoryview(vga)).intrinsics == Intrinsics(500.0, 500.0, 319.5, 239.5)


@pytest.mark.parametrize(
    ("k", "size"),
    [
        ((5e7, 5e7, 319.5, 239.5), (640, 480)),  # no lens has that focal length in pixels
        ((500.0, 50.0, 319.5, 239.5), (640, 480)),  # pixels ten times taller than wide
        ((500.0, 500.0, 900.0, 239.5), (640, 480)),  # principal point outside the image
        ((0.0, 0.0, 0.0, 0.0), (640, 480)),  # an uncalibrated camera's all-zero K
    ],
)
def test_implausible_intrinsics_are_refused(
    k: tuple[float, float, float, float], size: tuple[int, int]
) -> None:
    with pytest.raises(IntrinsicsError) as info:
        decode_camera_info(camera_info_cdr(*k, width=size[0], height=size[1]))
    assert info.value.reason == "bad_intrinsics"


@pytest.mark.parametrize(
    "payload",
    [b"", b"\x00\x01\x00\x00garbage", camera_info_cdr(500.0, 500.0, 319.5, 239.5)[:-8]],
    ids=["empty", "garbage", "truncated"],
)
def test_what_is_not_camera_info_is_refused(payload: bytes) -> None:
    with pytest.raises(CameraInfoError) as info:
        decode_camera_info(payload)
    assert info.value.reason == "bad_camera_info"


@given(st.binary(max_size=512))
def test_any_bytes_give_intrinsics_or_a_typed_error(payload: bytes) -> None:
    try:
        got = decode_camera_info(payload).intrinsics
    except (CameraInfoError, IntrinsicsError):
        return
    assert all(np.isfinite([got.fx, got.fy, got.cx, got.cy]))


_GOOD = camera_info_cdr(500.0, 500.0, 319.5, 239.5)


@given(data=st.data())
def test_mutated_camera_info_gives_intrinsics_or_a_typed_error(data: st.DataObject) -> None:
    raw = bytearray(_GOOD)
    for _ in range(data.draw(st.integers(min_value=1, max_value=6))):
        index = data.draw(st.integers(min_value=0, max_value=len(raw) - 1))
        raw[index] = data.draw(st.integers(min_value=0, max_value=255))
    try:
        got = decode_camera_info(bytes(raw)).intrinsics
    except (CameraInfoError, IntrinsicsError):
        return
    # whatever is accepted passed the plausibility check
    assert got.fx > 0 and got.fy > 0 and np.isfinite(got.cx) and np.isfinite(got.cy)


def test_the_image_size_comes_with_the_intrinsics() -> None:
    info = decode_camera_info(camera_info_cdr(700.5, 701.25, 640.0, 360.5, width=1280, height=720))
    assert (info.width, info.height) == (1280, 720)


def test_a_payload_larger_than_any_camera_info_is_refused_unread() -> None:
    with pytest.raises(CameraInfoError) as info:
        decode_camera_info(b"\x00" * (MAX_CAMERA_INFO_BYTES + 1))
    assert info.value.reason == "camera_info_too_large"
