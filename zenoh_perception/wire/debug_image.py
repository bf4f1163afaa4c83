"""The annotated debug image: detections outlined with ids, the selected tag highlighted, each
tag's axes where its pose is known (x red, y green, z blue, half the tag's side long), labels in
a dark box so they read on any background; JPEG-compressed and wrapped as
sensor_msgs/msg/CompressedImage CDR (what RViz and Foxglove show through zenoh-bridge-ros2dds)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.tags.selection import TagMessage, TagObservation
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, TYPESTORE, header

_OTHER = (0, 200, 255)  # BGR amber
_SELECTED = (0, 255, 0)  # BGR green
_BOX = (0, 0, 0)  # behind every label
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_NO_DISTORTION = np.zeros(5, np.float64)  # the frames are rectified


def _label(
    bgr: npt.NDArray[np.uint8],
    text: str,
    origin: tuple[int, int],
    colour: tuple[int, int, int],
    *,
    scale: float,
    thickness: int,
) -> None:
    """``text`` at ``origin`` (its baseline's left end) on a filled dark box."""
    (width, height), baseline = cv2.getTextSize(text, _FONT, scale, thickness)
    x, y = origin
    pad = max(1, thickness)
    cv2.rectangle(
        bgr, (x - pad, y - height - pad), (x + width + pad, y + baseline), _BOX, cv2.FILLED
    )
    cv2.putText(bgr, text, (x, y), _FONT, scale, colour, thickness, cv2.LINE_AA)


def annotate(
    bgr: npt.NDArray[np.uint8],
    tags: Sequence[TagObservation],
    selected: TagMessage,
    *,
    intrinsics: Intrinsics | None = None,
    tag_size: Callable[[int], float] | None = None,
) -> npt.NDArray[np.uint8]:
    """Draw every tag on ``bgr`` (in place) and return it; with ``intrinsics`` and
    ``tag_size`` (metres, by id), the axes of every tag that has a pose."""
    scale = max(bgr.shape[0], 480) / 480.0
    thickness = max(1, round(2 * scale))
    camera = None if intrinsics is None else intrinsics.matrix()
    for tag in tags:
        is_selected = tag.tag_id == selected.tag_id and (
            abs(tag.x - selected.x_tag_center_pixel) < 0.5
            and abs(tag.y - selected.y_tag_center_pixel) < 0.5
        )
        colour = _SELECTED if is_selected else _OTHER
        quad = np.round(np.asarray(tag.corners, dtype=np.float64)).astype(np.int32)
        cv2.polylines(
            bgr, [quad.reshape(-1, 1, 2)], True, colour, thickness * (2 if is_selected else 1)
        )
        centre = (round(tag.x), round(tag.y))
        cv2.circle(bgr, centre, thickness * 2, colour, -1)
        if camera is not None and tag_size is not None:
            _draw_axes(bgr, tag, camera, tag_size(tag.tag_id) / 2.0, thickness)
        label = f"id {tag.tag_id} c={tag.closeness:.2f}"
        origin = (int(quad[0][0]), max(int(quad[0][1]) - 6, round(14 * scale)))
        _label(bgr, label, origin, colour, scale=0.5 * scale, thickness=thickness)
    if selected.tag_id < 0:
        _label(
            bgr,
            "no tag",
            (10, round(24 * scale)),
            (0, 0, 255),
            scale=0.7 * scale,
            thickness=thickness,
        )
    return bgr


def _draw_axes(
    bgr: npt.NDArray[np.uint8],
    tag: TagObservation,
    camera: npt.NDArray[np.float64],
    length_m: float,
    thickness: int,
) -> None:
    if tag.rvec is None or tag.tvec is None or length_m <= 0.0 or tag.tvec[2] <= 0.0:
        return  # no pose, or one behind the camera (nothing to draw)
    cv2.drawFrameAxes(
        bgr,
        camera,
        _NO_DISTORTION,
        np.asarray(tag.rvec, np.float64),
        np.asarray(tag.tvec, np.float64),
        length_m,
        thickness,
    )


def encode_compressed_image(
    bgr: npt.NDArray[np.uint8], *, quality: int, stamp_ns: int, frame_id: str
) -> memoryview:
    """JPEG-encode ``bgr`` into sensor_msgs/msg/CompressedImage CDR."""
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - imencode only fails on invalid images
        msg = "JPEG encoding failed"
        raise ValueError(msg)
    message = TYPESTORE.types[COMPRESSED_IMAGE_TYPE](
        header=header(stamp_ns, frame_id),
        format="jpeg",
        data=np.asarray(jpeg, dtype=np.uint8).reshape(-1),
    )
    raw: memoryview = TYPESTORE.serialize_cdr(message, COMPRESSED_IMAGE_TYPE)
    return raw
