"""What a camera publishes unless told otherwise: the key the service reads, the bag topic of
that key, the rate of image folders and the frame id of videos and images."""

from __future__ import annotations

from pathlib import Path

from tests.camera.recordings import N_FRAMES, write_images
from zenoh_perception.camera.defaults import (
    DEFAULT_FRAME_ID,
    DEFAULT_KEY,
    DEFAULT_RATE_HZ,
    DEFAULT_TOPIC,
)
from zenoh_perception.camera.replay import ReplayOptions
from zenoh_perception.camera.sources import choose_image_topic, open_source
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import decode_attachment
from zenoh_perception.wire.messages import IMAGE_TYPE


def test_cameras_publish_where_the_service_reads() -> None:
    assert Settings().inputs.input_key == DEFAULT_KEY
    assert ReplayOptions().key == DEFAULT_KEY


def test_the_default_topic_is_the_ros_name_of_the_default_key() -> None:
    # zenoh-bridge-ros2dds maps the ROS topic /a/b to the Zenoh key a/b
    assert DEFAULT_TOPIC == "/" + DEFAULT_KEY
    topics = {"/zed/right/image": IMAGE_TYPE, DEFAULT_TOPIC: IMAGE_TYPE}
    assert choose_image_topic(topics, None) == DEFAULT_TOPIC


def test_an_image_folder_plays_at_the_default_rate_as_the_default_frame(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    frames = list(open_source(folder).frames(epoch_ns=0))
    assert len(frames) == N_FRAMES
    period_ns = round(1e9 / DEFAULT_RATE_HZ)
    assert [f.stamp_ns for f in frames] == [i * period_ns for i in range(N_FRAMES)]
    assert {decode_attachment(f.attachment).frame_id for f in frames} == {DEFAULT_FRAME_ID}
