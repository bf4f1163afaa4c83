"""Every detection of a frame as apriltag_msgs/msg/AprilTagDetectionArray CDR, the message
apriltag_ros publishes (and RViz plugins, apriltag_ros-based nodes and Foxglove read).

Per tag: ``family`` the ArUco dictionary's name (``DICT_4X4_50``), ``id``, ``centre`` and
``corners`` in pixels (OpenCV's corner order: top-left, top-right, bottom-right, bottom-left of
the marker, which is the order apriltag gives its corners in too), and ``homography``. OpenCV's
ArUco detector reports neither the bits it corrected nor a decision margin: ``hamming``,
``goodness`` and ``decision_margin`` are 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.tags.selection import TagObservation
from zenoh_perception.wire.messages import (
    APRILTAG_DETECTION_ARRAY_TYPE,
    TYPESTORE,
    header,
)
from zenoh_perception.wire.ros_topics import ros_topic

#: The output: its type and the setting of its key (the ROS topic /perception/detections).
DETECTIONS_TOPIC: Final = ros_topic("detections")

#: The tag's own frame in apriltag's convention: the homography maps the square
#: [-1, 1] x [-1, 1] (side 2, centre 0) onto the image, corner i of the detection being the
#: image of _TAG_SQUARE[i]: (-1, -1), (1, -1), (1, 1), (-1, 1). With y down like the image's,
#: that is top-left, top-right, bottom-right, bottom-left: OpenCV's order.
_TAG_SQUARE: Final = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]], np.float32)
_NO_HOMOGRAPHY: Final = np.zeros(9, np.float64)


def homography(corners: Sequence[tuple[float, float]]) -> npt.NDArray[np.float64]:
    """The 3x3 homography (row-major, 9 values, ``h[8] == 1``) from apriltag's tag square to
    ``corners``; zeros when the corners are degenerate (three of them on one line)."""
    points = np.asarray(corners, dtype=np.float32).reshape(4, 2)
    if not np.all(np.isfinite(points)) or _has_collinear_triple(points.astype(np.float64)):
        return _NO_HOMOGRAPHY.copy()
    try:
        matrix = cv2.getPerspectiveTransform(_TAG_SQUARE, points)
    except cv2.error:
        return _NO_HOMOGRAPHY.copy()
    flat = np.asarray(matrix, np.float64).reshape(9)
    return flat if np.all(np.isfinite(flat)) else _NO_HOMOGRAPHY.copy()


def _has_collinear_triple(points: npt.NDArray[np.float64]) -> bool:
    """Whether three of the four points lie on one line (no homography maps a square there)."""
    scale = max(float(np.abs(points - points.mean(axis=0)).max()), 1e-12)
    for i in range(4):
        a, b, c = points[i], points[(i + 1) % 4], points[(i + 2) % 4]
        cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if abs(cross) <= 1e-9 * scale * scale:
            return True
    return False


def encode_detections(
    tags: Sequence[TagObservation], *, family: str, stamp_ns: int, frame_id: str
) -> memoryview:
    """AprilTagDetectionArray CDR: the frame's header and one detection per tag, in order; a
    detection's family is the dictionary its tag names, else ``family``."""
    types = TYPESTORE.types
    point = types["apriltag_msgs/msg/Point"]
    detection = types["apriltag_msgs/msg/AprilTagDetection"]
    detections = [
        detection(
            family=tag.dictionary or family,
            id=int(tag.tag_id),
            hamming=0,
            goodness=0.0,
            decision_margin=0.0,
            centre=point(x=float(tag.x), y=float(tag.y)),
            corners=[point(x=float(x), y=float(y)) for x, y in tag.corners],
            homography=homography(tag.corners),
        )
        for tag in tags
    ]
    message = types[APRILTAG_DETECTION_ARRAY_TYPE](
        header=header(stamp_ns, frame_id), detections=detections
    )
    raw: memoryview = TYPESTORE.serialize_cdr(message, APRILTAG_DETECTION_ARRAY_TYPE)
    return raw
