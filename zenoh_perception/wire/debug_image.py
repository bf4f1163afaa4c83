"""The annotated debug image: detections outlined with ids, the selected tag highlighted,
JPEG-compressed and wrapped as sensor_msgs/msg/CompressedImage CDR (what RViz and Foxglove show
through zenoh-bridge-ros2dds)."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.tags.selection import TagMessage, TagObservation
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, TYPESTORE, header

_OTHER = (0, 200, 255)  # BGR amber
_SELECTED = (0, 255, 0)  # BGR green


def annotate(
    bgr: npt.NDArray[np.uint8], tags: Sequence[TagObservation], selected: TagMessage
) -> npt.NDArray[np.uint8]:
    """Draw every tag on ``bgr`` (in place) and return it."""
    scale = max(bgr.shape[0], 480) / 480.0
    thickness = max(1, round(2 * scale))
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
        label = f"id {tag.tag_id} c={tag.closeness:.2f}"
        cv2.putText(
            bgr,
            label,
            (int(quad[0][0]), max(int(quad[0][1]) - 6, 12)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5 * scale,
            colour,
            thickness,
            cv2.LINE_AA,
        )
    if selected.tag_id < 0:
        cv2.putText(
            bgr,
            "no tag",
            (10, round(24 * scale)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.7 * scale,
            (0, 0, 255),
            thickness,
            cv2.LINE_AA,
        )
    return bgr


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
