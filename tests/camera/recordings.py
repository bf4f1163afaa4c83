"""Recordings written by the tests: a rosbag2 (MCAP or SQLite) of sensor_msgs/msg/Image, an MJPG
video and a folder of PNG images, each of N_FRAMES frames with one known tag each."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
from rosbags.rosbag2 import StoragePlugin, Writer

from zenoh_perception.wire.frames import (
    encode_image_cdr,
)
from zenoh_perception.wire.messages import IMAGE_TYPE, TYPESTORE
from zenoh_perception_bench.scene import render_markers

Pixels = npt.NDArray[np.uint8]


W, H = 640, 360


N_FRAMES = 10


TOPIC = "/zed/left/image"


FRAME_ID = "zed_left_camera_optical_frame"


#: Header stamps: distinct, odd nanoseconds, 100 ms apart. The bag's receive times are 1.5 ms
#: later, so a record carrying the header stamp proves the CDR passed through unchanged.
HEADER_STAMPS = [1_700_000_000_123_456_789 + i * 100_000_000 + 7 * i for i in range(N_FRAMES)]


BAG_TIMES = [stamp + 1_500_000 for stamp in HEADER_STAMPS]


TAG_IDS = [(3 * i + 1) % 50 for i in range(N_FRAMES)]


def square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def scene_frame(index: int, width: int = W, height: int = H) -> Pixels:
    """A BGRA frame with marker ``TAG_IDS[index]`` at a position that moves with ``index``."""
    side = height // 3
    x0 = 20 + index * (width - side - 40) / max(1, N_FRAMES - 1)
    return render_markers(width, height, [(TAG_IDS[index], square(x0, height / 3, side))])


def to_bgr(bgra: Pixels) -> Pixels:
    return np.asarray(cv2.cvtColor(bgra, cv2.COLOR_BGRA2BGR), dtype=np.uint8)


def image_cdr(pixels: Pixels, encoding: str, stamp_ns: int, frame_id: str) -> bytes:
    """sensor_msgs/msg/Image CDR as a ROS 2 camera driver sends it (byte-identical to rosbags'
    own serialisation: tests/wire/test_frames.py checks that)."""
    return bytes(encode_image_cdr(pixels, encoding, stamp_ns=stamp_ns, frame_id=frame_id))


def write_bag(
    path: Path,
    plugin: StoragePlugin,
    *,
    extra_topics: Sequence[tuple[str, str]] = (("/chatter", "std_msgs/msg/String"),),
) -> list[bytes]:
    """A rosbag2 with ``N_FRAMES`` Image messages on TOPIC (plus other topics); the CDR."""
    written: list[bytes] = []
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        images = writer.add_connection(TOPIC, IMAGE_TYPE, typestore=TYPESTORE)
        others = [
            writer.add_connection(name, msgtype, typestore=TYPESTORE)
            for name, msgtype in extra_topics
        ]
        string_type = TYPESTORE.types["std_msgs/msg/String"]
        for i in range(N_FRAMES):
            data = image_cdr(scene_frame(i), "bgra8", HEADER_STAMPS[i], FRAME_ID)
            writer.write(images, BAG_TIMES[i], data)
            written.append(data)
            for conn in others:
                if conn.msgtype == "std_msgs/msg/String":
                    text = bytes(TYPESTORE.serialize_cdr(string_type(data=f"m{i}"), conn.msgtype))
                    writer.write(conn, BAG_TIMES[i] + 1, text)
    return written


def write_video(path: Path, fps: float = 20.0) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, (W, H))
    assert writer.isOpened()
    try:
        for i in range(N_FRAMES):
            writer.write(to_bgr(scene_frame(i)))
    finally:
        writer.release()


def write_images(folder: Path) -> list[Pixels]:
    """PNG frames named so that name order differs from write order; BGR pixels in name order."""
    folder.mkdir()
    order = list(reversed(range(N_FRAMES)))  # written last to first
    for i in order:
        assert cv2.imwrite(str(folder / f"frame_{i:03d}.png"), to_bgr(scene_frame(i, 320, 180)))
    (folder / "notes.txt").write_text("not an image")
    return [to_bgr(scene_frame(i, 320, 180)) for i in range(N_FRAMES)]
