"""What a camera publishes unless told otherwise: the key, frame id and image rate."""

from __future__ import annotations

from typing import Final

#: The key the ZED publishes its left image on, and the service reads.
DEFAULT_KEY: Final = "zed/left/image"
#: The key image_transport's compressed plugin publishes the left image on (replay --compressed).
DEFAULT_COMPRESSED_KEY: Final = "zed/left/image/compressed"
#: Topic preferred when a bag holds several sensor_msgs/msg/Image topics.
DEFAULT_TOPIC: Final = "/zed/left/image"
#: Frame rate of image folders (and of videos that do not state theirs).
DEFAULT_RATE_HZ: Final = 10.0
#: ``header.frame_id`` of frames read from videos and images.
DEFAULT_FRAME_ID: Final = "camera"
