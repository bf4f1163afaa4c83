"""ROS 2 wire compatibility, checked against rosbags (the reference CDR implementation here).

- ``tag``: byte-identical to rosbags' serialisation of StarterProjectTag (golden bytes, commented
  field by field, and a property test over the whole int32 / float32 ranges).
- sensor_msgs/msg/Image CDR produced by rosbags decodes to the same pixels for every supported
  encoding, with and without row padding, little- and big-endian; grey conversion from each
  encoding equals OpenCV's conversion of the equivalent BGR image.
"""

from __future__ import annotations

import math
import struct

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import REPO
from zenoh_perception.tags.selection import NO_TAG, TagMessage
from zenoh_perception.wire.frames import ENCODINGS, decode_image_cdr, encode_image_cdr, to_gray
from zenoh_perception.wire.messages import (
    IMAGE_TYPE,
    STARTER_PROJECT_TAG_MSG,
    TYPESTORE,
    header,
    make_typestore,
    tag_type_name,
)
from zenoh_perception.wire.records import TAG_CDR_SIZE, TagCodec

Pixels = npt.NDArray[np.uint8]

INT32 = st.integers(min_value=-(2**31), max_value=2**31 - 1)
FLOAT32 = st.floats(width=32, allow_nan=True, allow_infinity=True)


def _rosbags_tag_cdr(msg: TagMessage, package: str = "mrover") -> bytes:
    """The tag as rosbags serialises it, from a typestore built here (not the codec's)."""
    store = make_typestore(package)
    name = tag_type_name(package)
    instance = store.types[name](
        tag_id=msg.tag_id,
        x_tag_center_pixel=msg.x_tag_center_pixel,
        y_tag_center_pixel=msg.y_tag_center_pixel,
        closeness_metric=msg.closeness_metric,
    )
    return bytes(store.serialize_cdr(instance, name, little_endian=True))


def _f32_bits(value: float) -> bytes:
    return struct.pack("<f", value)


def _same_message(a: TagMessage, b: TagMessage) -> bool:
    """Equal field by field, NaN equal to NaN with the same bits."""
    return a.tag_id == b.tag_id and all(
        _f32_bits(x) == _f32_bits(y)
        for x, y in [
            (a.x_tag_center_pixel, b.x_tag_center_pixel),
            (a.y_tag_center_pixel, b.y_tag_center_pixel),
            (a.closeness_metric, b.closeness_metric),
        ]
    )


# -- tag: golden bytes -------------------------------------------------------------------------

# Every sample: 4-byte encapsulation header (00 01 = CDR little-endian, 00 00 = options), then
# int32 tag_id, float32 x_tag_center_pixel, float32 y_tag_center_pixel, float32
# closeness_metric, all little-endian, naturally aligned (no padding: 4-byte fields after a
# 4-byte header).
GOLDEN: list[tuple[TagMessage, str]] = [
    (
        TagMessage(7, 640.5, 360.25, 0.125),
        "00 01 00 00"  # header: CDR_LE, options 0
        " 07 00 00 00"  # tag_id 7
        " 00 20 20 44"  # x 640.5 = 0x44202000
        " 00 20 b4 43"  # y 360.25 = 0x43b42000
        " 00 00 00 3e",  # closeness 0.125 = 0x3e000000
    ),
    (
        NO_TAG,  # the dummy published when no tag is seen
        "00 01 00 00"  # header
        " ff ff ff ff"  # tag_id -1 (two's complement)
        " 00 00 00 00"  # x 0.0
        " 00 00 00 00"  # y 0.0
        " 00 00 00 00",  # closeness 0.0
    ),
    (
        TagMessage(-(2**31), -12.75, -0.0, 3.4028234663852886e38),
        "00 01 00 00"  # header
        " 00 00 00 80"  # tag_id INT32_MIN
        " 00 00 4c c1"  # x -12.75 = 0xc14c0000 (sign bit set)
        " 00 00 00 80"  # y -0.0: only the sign bit
        " ff ff 7f 7f",  # closeness FLT_MAX = 0x7f7fffff
    ),
    (
        TagMessage(2**31 - 1, math.nan, math.inf, -math.inf),
        "00 01 00 00"  # header
        " ff ff ff 7f"  # tag_id INT32_MAX
        " 00 00 c0 7f"  # x NaN (quiet NaN 0x7fc00000)
        " 00 00 80 7f"  # y +inf = 0x7f800000
        " 00 00 80 ff",  # closeness -inf = 0xff800000
    ),
    (
        TagMessage(49, 0.1, 1e-45, 1.0),
        "00 01 00 00"  # header
        " 31 00 00 00"  # tag_id 49 (last id of DICT_4X4_50)
        " cd cc cc 3d"  # x 0.1 rounded to the nearest float32 0x3dcccccd
        " 01 00 00 00"  # y 1e-45 -> smallest subnormal float32 0x00000001
        " 00 00 80 3f",  # closeness 1.0 = 0x3f800000
    ),
]


@pytest.mark.parametrize(("msg", "golden_hex"), GOLDEN)
def test_tag_matches_golden_bytes_and_rosbags(msg: TagMessage, golden_hex: str) -> None:
    golden = bytes.fromhex(golden_hex)
    assert len(golden) == TAG_CDR_SIZE
    assert _rosbags_tag_cdr(msg) == golden
    assert bytes(TagCodec().encode(msg)) == golden
    decoded = TagCodec().decode(golden)
    expected = TagMessage(
        msg.tag_id,
        *(struct.unpack("<f", _f32_bits(v))[0] for v in _fields(msg)),
    )
    assert _same_message(decoded, expected)


def _fields(msg: TagMessage) -> tuple[float, float, float]:
    return (msg.x_tag_center_pixel, msg.y_tag_center_pixel, msg.closeness_metric)


@given(tag_id=INT32, x=FLOAT32, y=FLOAT32, closeness=FLOAT32)
def test_tag_is_rosbags_serialisation_for_all_ids_and_floats(
    tag_id: int, x: float, y: float, closeness: float
) -> None:
    msg = TagMessage(tag_id, x, y, closeness)
    encoded = bytes(TagCodec().encode(msg))
    assert encoded == _rosbags_tag_cdr(msg)
    # An independent oracle of the layout: header, then "<i f f f".
    assert encoded == b"\x00\x01\x00\x00" + struct.pack("<i3f", tag_id, x, y, closeness)
    assert _same_message(TagCodec().decode(encoded), msg)


@given(tag_id=INT32, x=FLOAT32, y=FLOAT32, closeness=FLOAT32)
def test_ros_package_changes_the_type_name_not_the_bytes(
    tag_id: int, x: float, y: float, closeness: float
) -> None:
    msg = TagMessage(tag_id, x, y, closeness)
    default, custom = TagCodec(), TagCodec("my_robot_msgs")
    assert (default.type_name, custom.type_name) == (
        "mrover/msg/StarterProjectTag",
        "my_robot_msgs/msg/StarterProjectTag",
    )
    encoded = bytes(custom.encode(msg))
    assert encoded == bytes(default.encode(msg)) == _rosbags_tag_cdr(msg, "my_robot_msgs")
    assert _same_message(default.decode(encoded), msg)


def test_tag_from_a_big_endian_ros_publisher_decodes() -> None:
    # CDR_BE (00 00) is legal on the wire; a big-endian ROS 2 node would send it.
    msg = TagMessage(12, 100.5, -3.25, 0.75)
    store = make_typestore()
    name = tag_type_name()
    instance = store.types[name](
        tag_id=12, x_tag_center_pixel=100.5, y_tag_center_pixel=-3.25, closeness_metric=0.75
    )
    big = bytes(store.serialize_cdr(instance, name, little_endian=False))
    assert big == bytes.fromhex("00 00 00 00 00 00 00 0c 42 c9 00 00 c0 50 00 00 3f 40 00 00")
    assert _same_message(TagCodec().decode(big), msg)


def test_schema_msg_file_is_the_registered_definition() -> None:
    text = (REPO / "schemas" / "StarterProjectTag.msg").read_text(encoding="utf-8")
    assert text == STARTER_PROJECT_TAG_MSG
    fields = [line.split()[1] for line in text.splitlines() if line.strip()]
    assert fields == ["tag_id", "x_tag_center_pixel", "y_tag_center_pixel", "closeness_metric"]


# -- sensor_msgs/msg/Image ---------------------------------------------------------------------


def _rosbags_image_cdr(
    pixels: Pixels,
    encoding: str,
    *,
    padding: int,
    little_endian: bool,
    stamp_ns: int = 1_700_000_001_000_000_123,
    frame_id: str = "zed_left_camera_optical_frame",
    pad_byte: int = 0xA5,
) -> bytes:
    """Image CDR built and serialised by rosbags; rows padded with ``pad_byte``."""
    height, width = pixels.shape[:2]
    row = pixels.reshape(height, -1)
    step = row.shape[1] + padding
    data = np.full((height, step), pad_byte, dtype=np.uint8)
    data[:, : row.shape[1]] = row
    types = TYPESTORE.types
    msg = types[IMAGE_TYPE](
        header=header(stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=data.reshape(-1),
    )
    return bytes(TYPESTORE.serialize_cdr(msg, IMAGE_TYPE, little_endian=little_endian))


def _random_pixels(height: int, width: int, channels: int, seed: int) -> Pixels:
    rng = np.random.default_rng(seed)
    shape = (height, width) if channels == 1 else (height, width, channels)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


ENDIANNESS = pytest.mark.parametrize("little_endian", [True, False], ids=["le", "be"])
PADDING = pytest.mark.parametrize("padding", [0, 1, 3, 64])


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@PADDING
@ENDIANNESS
@pytest.mark.parametrize(("height", "width"), [(7, 13), (48, 64)])
def test_rosbags_image_decodes_to_the_same_pixels(
    encoding: str, padding: int, little_endian: bool, height: int, width: int
) -> None:
    pixels = _random_pixels(height, width, ENCODINGS[encoding].channels, seed=height + padding)
    payload = _rosbags_image_cdr(pixels, encoding, padding=padding, little_endian=little_endian)
    assert payload[:2] == (b"\x00\x01" if little_endian else b"\x00\x00")
    frame = decode_image_cdr(payload)
    assert frame.encoding.name == encoding
    assert (frame.width, frame.height) == (width, height)
    assert frame.pixels.shape == pixels.shape
    np.testing.assert_array_equal(frame.pixels, pixels)
    assert frame.stamp_ns == 1_700_000_001_000_000_123
    assert frame.frame_id == "zed_left_camera_optical_frame"


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("padding", [0, 8])
def test_encode_image_cdr_is_byte_identical_to_rosbags(encoding: str, padding: int) -> None:
    pixels = _random_pixels(5, 9, ENCODINGS[encoding].channels, seed=3)
    row_bytes = 9 * ENCODINGS[encoding].channels
    ours = encode_image_cdr(
        pixels,
        encoding,
        stamp_ns=1_700_000_001_000_000_123,
        frame_id="zed_left_camera_optical_frame",
        step=row_bytes + padding,
    )
    reference = _rosbags_image_cdr(
        pixels, encoding, padding=padding, little_endian=True, pad_byte=0
    )
    assert bytes(ours) == reference


def _as_encoding(bgr: Pixels, encoding: str, seed: int) -> Pixels:
    """The same picture in ``encoding`` (alpha random: it must not affect grey)."""
    alpha = _random_pixels(bgr.shape[0], bgr.shape[1], 1, seed)
    if encoding == "bgr8":
        return bgr
    if encoding == "rgb8":
        return np.ascontiguousarray(bgr[:, :, ::-1])
    if encoding == "bgra8":
        return np.dstack([bgr, alpha])
    if encoding == "rgba8":
        return np.dstack([bgr[:, :, ::-1], alpha])
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), dtype=np.uint8)  # mono8


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("padding", [0, 5])
@ENDIANNESS
def test_grey_from_every_encoding_matches_opencv_on_bgr(
    encoding: str, padding: int, little_endian: bool
) -> None:
    bgr = _random_pixels(31, 47, 3, seed=11)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    pixels = _as_encoding(bgr, encoding, seed=12)
    frame = decode_image_cdr(
        _rosbags_image_cdr(pixels, encoding, padding=padding, little_endian=little_endian)
    )
    gray = to_gray(frame)
    assert gray.shape == (31, 47)
    np.testing.assert_array_equal(gray, expected)
