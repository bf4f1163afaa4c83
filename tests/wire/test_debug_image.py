"""The debug image: the tags outlined (the selected one in green, the others in amber), JPEG in
sensor_msgs/msg/CompressedImage CDR with the frame's stamp and frame id."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.tags.selection import NO_TAG, TagObservation
from zenoh_perception.wire.debug_image import annotate, encode_compressed_image
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, TYPESTORE

Pixels = npt.NDArray[np.uint8]
GREEN, AMBER, RED = (0, 255, 0), (0, 200, 255), (0, 0, 255)  # BGR

#: The last instant builtin_interfaces/Time (int32 seconds) can hold.
ROS_TIME_MAX_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999


def _message(payload: bytes) -> Any:
    return TYPESTORE.deserialize_cdr(payload, COMPRESSED_IMAGE_TYPE)


def _stamp_of(sample_payload: bytes) -> int:
    msg = _message(sample_payload)
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _tag(tag_id: int, x0: float, y0: float, side: float) -> TagObservation:
    corners = ((x0, y0), (x0 + side, y0), (x0 + side, y0 + side), (x0, y0 + side))
    centre = x0 + side / 2, y0 + side / 2
    return TagObservation(tag_id, centre[0], centre[1], 0.5, corners, side * side)


def _colour_at(image: Pixels, x: float, y: float) -> tuple[int, int, int]:
    b, g, r = (int(v) for v in image[round(y), round(x)])
    return b, g, r


def test_the_selected_tag_is_green_the_others_amber() -> None:
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    chosen, other = _tag(5, 100, 120, 200), _tag(21, 420, 160, 110)
    out = annotate(image, [chosen, other], chosen.message())
    assert out is image  # drawn in place
    for x, y in [(200, 120), (300, 220), (200, 320), (100, 220)]:  # edge midpoints
        assert _colour_at(image, x, y) == GREEN
    for x, y in [(475, 160), (530, 215), (475, 270), (420, 215)]:
        assert _colour_at(image, x, y) == AMBER
    assert _colour_at(image, 200, 220) == GREEN  # the centre dot
    assert not image[400:, :80].any()  # nothing drawn far from the tags


def test_the_same_id_elsewhere_is_not_the_selected_tag() -> None:
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    chosen, twin = _tag(5, 100, 120, 100), _tag(5, 400, 120, 100)
    annotate(image, [chosen, twin], chosen.message())
    assert _colour_at(image, 150, 120) == GREEN
    assert _colour_at(image, 450, 120) == AMBER


def test_no_tag_says_so_in_red() -> None:
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    annotate(image, [], NO_TAG)
    red = np.all(image == RED, axis=2)
    ys, xs = np.nonzero(red)
    assert red.sum() > 50
    assert xs.min() >= 10 and ys.max() < 40  # top left, nothing else
    assert not image[:, 200:].any() and not image[60:].any()


@pytest.mark.parametrize("height", [480, 1080])
def test_lines_thicken_with_the_image(height: int) -> None:
    width = height * 4 // 3
    image = np.zeros((height, width, 3), dtype=np.uint8)
    tag = _tag(1, width / 4, height / 4, height / 2)
    annotate(image, [tag], tag.message())
    column = np.all(image[:, round(width / 4) - 20 : round(width / 4) + 20] == GREEN, axis=2)
    thickness = int(column[height // 2].sum())  # across the left edge, half way down
    assert thickness == pytest.approx(4 * height / 480, abs=1.5)


def test_the_compressed_image_carries_the_jpeg_stamp_and_frame_id() -> None:
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    image = np.asarray(cv2.GaussianBlur(noise, (9, 9), 3), dtype=np.uint8)
    payload = bytes(
        encode_compressed_image(
            image, quality=95, stamp_ns=1_700_000_000_123_456_789, frame_id="cam"
        )
    )
    msg = _message(payload)
    assert (msg.format, msg.header.frame_id) == ("jpeg", "cam")
    assert _stamp_of(payload) == 1_700_000_000_123_456_789
    decoded = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
    assert decoded is not None
    assert decoded.shape == image.shape
    assert np.abs(decoded.astype(np.int16) - image).mean() < 3.0


def test_lower_quality_is_fewer_bytes() -> None:
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    sizes = [
        len(encode_compressed_image(image, quality=q, stamp_ns=0, frame_id="f"))
        for q in (30, 60, 95)
    ]
    assert sizes == sorted(sizes) and sizes[0] < sizes[2] / 2


def test_a_stamp_ros_time_cannot_hold_is_clamped_in_the_debug_image() -> None:
    image = np.zeros((8, 8, 3), dtype=np.uint8)
    cdr = bytes(encode_compressed_image(image, quality=80, stamp_ns=2**62, frame_id="f"))
    assert _stamp_of(cdr) == ROS_TIME_MAX_NS


def _posed_tag(tag_id: int = 4) -> TagObservation:
    # 0.2 m tag 1 m ahead on the optical axis of VGA (f = 500): 100 px, facing the camera
    # (rvec: half a turn about x, so the tag's y axis points up the image, z at the camera)
    corners = ((270.0, 190.0), (370.0, 190.0), (370.0, 290.0), (270.0, 290.0))
    return TagObservation(
        tag_id, 320.0, 240.0, 0.5, corners, 1e4, 1.0, (np.pi, 0.0, 0.0), (0.0, 0.0, 1.0)
    )


VGA = Intrinsics(500.0, 500.0, 320.0, 240.0)


def test_a_tag_with_a_pose_gets_its_axes_x_red_y_green() -> None:
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    tag = _posed_tag()
    annotate(image, [tag], tag.message(), intrinsics=VGA, tag_size=lambda _id: 0.2)
    # half the side (0.1 m): 50 px from the centre
    assert _colour_at(image, 345, 240) == RED  # x to the right
    assert _colour_at(image, 320, 215) == GREEN  # y up the image
    plain = np.zeros_like(image)
    annotate(plain, [tag], tag.message())  # no intrinsics: no axes
    assert _colour_at(plain, 345, 240) == (0, 0, 0)


def test_no_axes_without_a_pose_or_a_size() -> None:
    image = np.zeros((480, 640, 3), dtype=np.uint8)
    tag = _posed_tag()
    annotate(image, [tag], tag.message(), intrinsics=VGA, tag_size=lambda _id: 0.0)
    assert _colour_at(image, 345, 240) == (0, 0, 0)


def test_labels_sit_on_a_dark_box_readable_on_white() -> None:
    image = np.full((480, 640, 3), 255, dtype=np.uint8)
    tag = _tag(5, 100, 200, 100)
    annotate(image, [tag], NO_TAG)
    label = image[180:196, 100:176]  # above the top-left corner, where the label goes
    dark = np.all(label < 40, axis=2).mean()
    assert dark > 0.4
    assert np.all(image[14:30, 10:80] < 40, axis=2).mean() > 0.4  # "no tag" on its box too
