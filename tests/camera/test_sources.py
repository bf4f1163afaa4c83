"""Replay frame sources: rosbag2 (MCAP and SQLite), videos and image folders, and their errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin

from tests.camera.recordings import (
    BAG_TIMES,
    FRAME_ID,
    HEADER_STAMPS,
    N_FRAMES,
    TOPIC,
    H,
    W,
    scene_frame,
    write_bag,
    write_images,
    write_video,
)
from zenoh_perception.camera.sources import (
    BagSource,
    ImageSequenceSource,
    ReplayError,
    VideoSource,
    choose_image_topic,
    list_images,
    open_source,
)
from zenoh_perception.wire.frames import (
    decode_attachment,
    decode_image_cdr,
    decode_raw_frame,
)
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, IMAGE_TYPE


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_bag_source_yields_the_original_cdr_bytes_and_bag_times(
    tmp_path: Path, plugin: StoragePlugin
) -> None:
    bag = tmp_path / "bag"
    written = write_bag(bag, plugin)
    storage_file = next(p for p in bag.iterdir() if p.suffix in {".mcap", ".db3"})
    for path in (bag, storage_file):
        source = open_source(path)
        assert isinstance(source, BagSource)
        assert (source.topic, source.count) == (TOPIC, N_FRAMES)
        frames = list(source.frames())
        assert [f.payload for f in frames] == written
        assert [f.attachment for f in frames] == [None] * N_FRAMES
        assert [f.stamp_ns for f in frames] == BAG_TIMES
        first = decode_image_cdr(frames[0].payload)
        assert (first.stamp_ns, first.frame_id) == (HEADER_STAMPS[0], FRAME_ID)


def test_bag_source_topic_choice_and_errors(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_bag(
        bag,
        StoragePlugin.MCAP,
        extra_topics=[("/chatter", "std_msgs/msg/String"), ("/compressed", COMPRESSED_IMAGE_TYPE)],
    )
    assert BagSource(bag, "zed/left/image").topic == TOPIC  # leading slash optional
    with pytest.raises(ReplayError, match="not sensor_msgs/msg/Image"):
        BagSource(bag, "/compressed")
    with pytest.raises(ReplayError, match="no topic '/missing'"):
        BagSource(bag, "/missing")
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not an mcap file")
    with pytest.raises(ReplayError, match="cannot read rosbag2"):
        BagSource(broken)


@pytest.mark.parametrize(
    ("topics", "requested", "expected"),
    [
        ({"/cam": IMAGE_TYPE, "/s": "std_msgs/msg/String"}, None, "/cam"),
        ({"/a": IMAGE_TYPE, TOPIC: IMAGE_TYPE}, None, TOPIC),
        ({"/a": IMAGE_TYPE, "/b": IMAGE_TYPE}, "/b", "/b"),
        ({"/a": IMAGE_TYPE, "/b": IMAGE_TYPE}, "b", "/b"),
    ],
)
def test_choose_image_topic(topics: dict[str, str], requested: str | None, expected: str) -> None:
    assert choose_image_topic(topics, requested) == expected


@pytest.mark.parametrize(
    ("topics", "match"),
    [
        ({"/a": IMAGE_TYPE, "/b": IMAGE_TYPE}, "several"),
        ({"/s": "std_msgs/msg/String"}, "has no sensor_msgs/msg/Image topic"),
        ({}, "has no sensor_msgs/msg/Image topic"),
    ],
)
def test_choose_image_topic_refuses_ambiguity(topics: dict[str, str], match: str) -> None:
    with pytest.raises(ReplayError, match=match):
        choose_image_topic(topics, None)


def test_video_source_sends_bgra_with_attachment(tmp_path: Path) -> None:
    video = tmp_path / "clip.avi"
    write_video(video, fps=25.0)
    source = open_source(video, frame_id="cam1")
    assert isinstance(source, VideoSource)
    assert source.fps == pytest.approx(25.0)
    frames = list(source.frames(epoch_ns=1_000, seq_start=40))
    assert len(frames) == N_FRAMES
    for i, frame in enumerate(frames):
        meta = decode_attachment(frame.attachment)
        assert (meta.width, meta.height, meta.encoding) == (W, H, "bgra8")
        assert (meta.seq, meta.frame_id) == (40 + i, "cam1")
        assert meta.stamp_ns == frame.stamp_ns == 1_000 + i * 40_000_000
        decoded = decode_raw_frame(frame.payload, frame.attachment)
        expected = scene_frame(i)[:, :, :3].astype(np.int16)
        # MJPG is lossy: close to the rendered frame, not equal.
        assert np.abs(decoded.pixels[:, :, :3].astype(np.int16) - expected).mean() < 4.0
        assert np.all(decoded.pixels[:, :, 3] == 255)


def test_image_folder_is_read_in_name_order_as_bgra(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    expected = write_images(folder)
    assert [p.name for p in list_images(folder)] == [f"frame_{i:03d}.png" for i in range(10)]
    source = open_source(folder, image_rate_hz=4.0, frame_id="still")
    assert isinstance(source, ImageSequenceSource)
    assert source.count == N_FRAMES
    frames = list(source.frames(epoch_ns=5, seq_start=0))
    for i, frame in enumerate(frames):
        decoded = decode_raw_frame(frame.payload, frame.attachment)
        np.testing.assert_array_equal(decoded.pixels[:, :, :3], expected[i])
        assert (decoded.seq, decoded.frame_id, decoded.encoding.name) == (i, "still", "bgra8")
        assert frame.stamp_ns == decoded.stamp_ns == 5 + i * 250_000_000


def test_single_image_and_unreadable_image(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    single = open_source(folder / "frame_003.png")
    assert single.count == 1
    assert len(list(single.frames())) == 1
    (folder / "frame_004.png").write_bytes(b"not a png")
    frames = open_source(folder).frames()
    with pytest.raises(ReplayError, match="cannot read the image"):
        list(frames)


@pytest.mark.parametrize(
    ("name", "content", "match"),
    [
        ("missing.avi", None, "no such file"),
        ("junk.avi", b"garbage" * 64, "cannot open"),
        ("empty", b"", "neither a rosbag2"),
    ],
)
def test_open_source_errors(tmp_path: Path, name: str, content: bytes | None, match: str) -> None:
    path = tmp_path / name
    if name == "empty":
        path.mkdir()
        (path / "readme.md").write_text("nothing here")
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(ReplayError, match=match):
        open_source(path)


def test_topic_is_refused_for_non_bag_sources(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    with pytest.raises(ReplayError, match="rosbag2 sources only"):
        open_source(folder, topic="/zed/left/image")
