"""``zenoh-perception replay``: frame sources, pacing, progress, and the real CLI end to end.

Bags are written with rosbags' Writer inside each test; they replay through a running
:class:`PerceptionService` and every frame must be answered with its ORIGINAL header stamp.
"""

from __future__ import annotations

import io
import itertools
import queue
import signal
import subprocess
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest
import zenoh
from rosbags.rosbag2 import StoragePlugin, Writer

from tests.helpers import Collector, loopback_config, open_session, running_cli
from zenoh_perception.camera.replay import (
    Pacer,
    Pacing,
    ProgressBar,
    ReplayOptions,
    main,
    render_progress,
)
from zenoh_perception.camera.sources import (
    BagSource,
    Frames,
    ImageSequenceSource,
    ReplayError,
    SourceFrame,
    VideoSource,
    choose_image_topic,
    list_images,
    open_source,
)
from zenoh_perception.scene import render_markers
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import (
    decode_attachment,
    decode_image_cdr,
    decode_raw_frame,
    encode_image_cdr,
)
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, TYPESTORE
from zenoh_perception.wire.records import decode_record

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
REPLAY_TIMEOUT_S = 60.0


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _scene(index: int, width: int = W, height: int = H) -> Pixels:
    """A BGRA frame with marker ``TAG_IDS[index]`` at a position that moves with ``index``."""
    side = height // 3
    x0 = 20 + index * (width - side - 40) / max(1, N_FRAMES - 1)
    return render_markers(width, height, [(TAG_IDS[index], _square(x0, height / 3, side))])


def _bgr(bgra: Pixels) -> Pixels:
    return np.asarray(cv2.cvtColor(bgra, cv2.COLOR_BGRA2BGR), dtype=np.uint8)


def _image_cdr(pixels: Pixels, encoding: str, stamp_ns: int, frame_id: str) -> bytes:
    """sensor_msgs/msg/Image CDR as a ROS 2 camera driver sends it (byte-identical to rosbags'
    own serialisation: tests/test_ros_interop.py checks that)."""
    return bytes(encode_image_cdr(pixels, encoding, stamp_ns=stamp_ns, frame_id=frame_id))


def _write_bag(
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
            data = _image_cdr(_scene(i), "bgra8", HEADER_STAMPS[i], FRAME_ID)
            writer.write(images, BAG_TIMES[i], data)
            written.append(data)
            for conn in others:
                if conn.msgtype == "std_msgs/msg/String":
                    text = bytes(TYPESTORE.serialize_cdr(string_type(data=f"m{i}"), conn.msgtype))
                    writer.write(conn, BAG_TIMES[i] + 1, text)
    return written


def _write_video(path: Path, fps: float = 20.0) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, (W, H))
    assert writer.isOpened()
    try:
        for i in range(N_FRAMES):
            writer.write(_bgr(_scene(i)))
    finally:
        writer.release()


def _write_images(folder: Path) -> list[Pixels]:
    """PNG frames named so that name order differs from write order; BGR pixels in name order."""
    folder.mkdir()
    order = list(reversed(range(N_FRAMES)))  # written last to first
    for i in order:
        assert cv2.imwrite(str(folder / f"frame_{i:03d}.png"), _bgr(_scene(i, 320, 180)))
    (folder / "notes.txt").write_text("not an image")
    return [_bgr(_scene(i, 320, 180)) for i in range(N_FRAMES)]


class _Lines:
    """Reads a subprocess's output lines on a thread so tests can wait for one."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        assert proc.stdout is not None
        self._thread = threading.Thread(target=self._read, args=(proc.stdout,), daemon=True)
        self._thread.start()

    def _read(self, stream: Any) -> None:
        for line in stream:
            self.lines.put(line)
        self.lines.put("")  # end of output

    def wait_for(self, text: str, timeout: float = 20.0) -> str:
        """The first line containing ``text``; fails at the end of the output."""
        while True:
            line = self.lines.get(timeout=timeout)
            self.seen.append(line)
            if text in line:
                return line
            if not line:
                pytest.fail(f"{text!r} not in the output:\n{''.join(self.seen)}")


@pytest.fixture
def service_session(endpoint: str) -> Iterator[zenoh.Session]:
    """A peer listening on ``endpoint`` with a started in-process service."""
    with open_session(listen=[endpoint]) as session:
        service = PerceptionService(session, Settings(stats_interval_s=0.0))
        with service:
            yield session


def _records(collector: Collector, count: int) -> list[dict[str, Any]]:
    return [decode_record(collector.get(timeout=REPLAY_TIMEOUT_S).payload) for _ in range(count)]


def _replay_args(path: Path, endpoint: str, *extra: str) -> list[str]:
    return [
        "replay",
        str(path),
        "-e",
        endpoint,
        "--no-multicast-scouting",
        "--subscriber-timeout",
        "30",
        *extra,
    ]


def _finish(proc: subprocess.Popen[str]) -> str:
    """Wait for the CLI to exit by itself; its whole output."""
    output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 0, output
    return output


# -- rosbag2 through the real CLI and a running service ----------------------------------------


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_bag_replays_through_the_service_with_original_stamps(
    tmp_path: Path, endpoint: str, service_session: zenoh.Session, plugin: StoragePlugin
) -> None:
    bag = tmp_path / "bag"
    _write_bag(bag, plugin)
    records = Collector(service_session, "perception/tags")
    with running_cli(*_replay_args(bag, endpoint)) as proc:
        got = _records(records, N_FRAMES)
        output = _finish(proc)
    assert [r["stamp_ns"] for r in got] == HEADER_STAMPS
    assert [r["selected"]["tag_id"] for r in got] == TAG_IDS
    assert {r["source"] for r in got} == {"cdr"}
    assert {r["frame_id"] for r in got} == {FRAME_ID}
    assert {(r["width"], r["height"]) for r in got} == {(W, H)}
    assert records.drain() == []
    assert f"event=replay_done published={N_FRAMES}" in output


def test_video_replays_through_the_service_with_seq_and_stamps(
    tmp_path: Path, endpoint: str, service_session: zenoh.Session
) -> None:
    video = tmp_path / "drive.avi"
    _write_video(video, fps=20.0)
    records = Collector(service_session, "perception/tags")
    with running_cli(*_replay_args(video, endpoint, "--frame-id", "cam0")) as proc:
        got = _records(records, N_FRAMES)
        _finish(proc)
    assert [r["seq"] for r in got] == list(range(N_FRAMES))
    assert [r["selected"]["tag_id"] for r in got] == TAG_IDS
    assert {r["source"] for r in got} == {"raw"}
    assert {r["frame_id"] for r in got} == {"cam0"}
    stamps = [r["stamp_ns"] for r in got]
    # Stamps follow the video's clock: 20 fps -> exactly 50 ms apart.
    assert [b - a for a, b in itertools.pairwise(stamps)] == [50_000_000] * 9


@pytest.mark.parametrize("kind", ["video", "bag"])
def test_shm_replay_is_answered_and_read_from_shared_memory(
    tmp_path: Path, endpoint: str, service_session: zenoh.Session, kind: str
) -> None:
    """``--shm``: raw frames (video) and CDR frames (bag) go from shared memory, the service
    answers every one, and on this machine the service side reads them in place. (Plain puts
    of large frames also arrive in shared memory once Zenoh's transport optimisation has copied
    them there, all but the first frames here: the replay's own counters tell the paths apart.)
    """
    if kind == "video":
        source = tmp_path / "drive.avi"
        _write_video(source, fps=20.0)
    else:
        source = tmp_path / "bag"
        _write_bag(source, StoragePlugin.MCAP)
    in_shm: queue.Queue[bool] = queue.Queue()
    frames = service_session.declare_subscriber(
        "zed/left/image", lambda sample: in_shm.put(sample.payload.as_shm() is not None)
    )
    records = Collector(service_session, "perception/tags")
    try:
        # 10 Hz: the service answers every frame even on a busy 2-core machine
        with running_cli(*_replay_args(source, endpoint, "--shm", "--rate", "10")) as proc:
            got = _records(records, N_FRAMES)
            output = _finish(proc)
        shm = [in_shm.get(timeout=REPLAY_TIMEOUT_S) for _ in range(N_FRAMES)]
    finally:
        frames.undeclare()
    assert [r["selected"]["tag_id"] for r in got] == TAG_IDS
    assert {r["source"] for r in got} == {"raw" if kind == "video" else "cdr"}
    assert shm == [True] * N_FRAMES
    assert "shm=True" in output
    assert f"shm_frames={N_FRAMES} plain_frames=0" in output


# -- sources -----------------------------------------------------------------------------------


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_bag_source_yields_the_original_cdr_bytes_and_bag_times(
    tmp_path: Path, plugin: StoragePlugin
) -> None:
    bag = tmp_path / "bag"
    written = _write_bag(bag, plugin)
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
    _write_bag(
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
    _write_video(video, fps=25.0)
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
        expected = _scene(i)[:, :, :3].astype(np.int16)
        # MJPG is lossy: close to the rendered frame, not equal.
        assert np.abs(decoded.pixels[:, :, :3].astype(np.int16) - expected).mean() < 4.0
        assert np.all(decoded.pixels[:, :, 3] == 255)


def test_image_folder_is_read_in_name_order_as_bgra(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    expected = _write_images(folder)
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
    _write_images(folder)
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
    _write_images(folder)
    with pytest.raises(ReplayError, match="rosbag2 sources only"):
        open_source(folder, topic="/zed/left/image")


# -- pacing (fake clock) and progress ---------------------------------------------------------


def test_recorded_pacing_keeps_the_recording_spacing() -> None:
    pacer = Pacer(Pacing.RECORDED)
    stamps = [10_000_000_000 + k for k in (0, 100_000_000, 150_000_000, 400_000_000)]
    # The sender is always on time: each frame is asked for when the previous was due.
    now = 50.0
    dues = []
    for stamp in stamps:
        due = pacer.due(stamp, now)
        dues.append(due)
        now = due
    assert dues == pytest.approx([50.0, 50.1, 50.15, 50.4])


def test_recorded_pacing_restarts_one_interval_after_a_loop() -> None:
    pacer = Pacer(Pacing.RECORDED)
    assert pacer.due(0, 10.0) == 10.0
    assert pacer.due(200_000_000, 10.0) == pytest.approx(10.2)
    # The next pass starts over at stamp 0: one interval after the last frame, then as recorded.
    assert pacer.due(0, 10.2) == pytest.approx(10.4)
    assert pacer.due(200_000_000, 10.4) == pytest.approx(10.6)


def test_fixed_rate_pacing_ignores_stamps_and_does_not_drift() -> None:
    pacer = Pacer(Pacing.RATE, 4.0)
    # Asked late each time (processing took 0.1 s): deadlines stay on the 0.25 s grid.
    dues = [pacer.due(stamp, 100.0 + 0.26 * i) for i, stamp in enumerate([9, 3, 7, 1])]
    assert dues == pytest.approx([100.0, 100.25, 100.5, 100.75])


def test_pacing_does_not_burst_after_a_stall() -> None:
    pacer = Pacer(Pacing.RATE, 10.0, max_lag_s=1.0)
    assert pacer.due(0, 0.0) == 0.0
    # Stalled 5 s (e.g. a slow disk): send now and continue from here, not 50 frames at once.
    assert pacer.due(0, 5.0) == 5.0
    assert pacer.due(0, 5.0) == pytest.approx(5.1)


def test_as_fast_as_possible_is_always_due_now() -> None:
    pacer = Pacer(Pacing.ASAP)
    assert [pacer.due(s, t) for s, t in [(5, 1.0), (0, 2.0), (9, 2.5)]] == [1.0, 2.0, 2.5]


def test_fixed_rate_pacing_needs_a_rate() -> None:
    with pytest.raises(ReplayError):
        Pacer(Pacing.RATE, None)
    with pytest.raises(ReplayError):
        Pacer(Pacing.RATE, float("nan"))


def test_render_progress() -> None:
    # Rate: frames after the first over the time since the first.
    assert render_progress(5, 10, 2.0, width=10) == "replay [#####.....]  50% 5/10 frames 2.0 fps"
    assert render_progress(10, 10, 1.5, width=4) == "replay [####] 100% 10/10 frames 6.0 fps"
    assert render_progress(7, None, 0.5) == "replay 7 frames 12.0 fps"
    assert render_progress(1, None, 0.0) == "replay 1 frames 0.0 fps"
    assert render_progress(3, 7, 1.0, width=7) == "replay [###....]  42% 3/7 frames 2.0 fps"


def test_progress_bar_redraws_in_place_and_throttles() -> None:
    stream = io.StringIO()
    bar = ProgressBar(stream, 4, min_interval_s=1.0)
    bar.update(1, 0.5)
    bar.update(2, 0.7)  # within the interval: not drawn
    bar.update(3, 1.6)
    bar.finish(4, 2.0)
    text = stream.getvalue()
    assert text.endswith("\n")
    draws = text.rstrip("\n").split("\r")[1:]
    assert [d.split()[3] for d in draws] == ["1/4", "3/4", "4/4"]


# -- the publishing loop in process -----------------------------------------------------------


class _ListSource:
    """An in-memory raw source whose payload is the frame number (for counting)."""

    kind = "test"

    def __init__(self, count: int) -> None:
        self._count = count

    @property
    def count(self) -> int | None:
        return self._count

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        for i in range(self._count):
            yield SourceFrame(f"{seq_start + i}".encode(), b"\x80", epoch_ns + i)


def test_main_loops_up_to_the_limit_and_draws_progress(endpoint: str) -> None:
    stream = io.StringIO()
    options = ReplayOptions(
        key="replay/test", pacing=Pacing.ASAP, loop=True, limit=23, progress=True
    )
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "replay/test")
        conf = loopback_config(connect=[endpoint])
        code = main(conf, _ListSource(5), options, threading.Event(), progress_stream=stream)
        got = [frames.get().payload.decode() for _ in range(23)]
    assert code == 0
    # Five frames per pass, numbered on across passes, stopped at 23.
    assert got == [str(i) for i in range(23)]
    assert frames.drain() == []
    assert "23/23 frames" in stream.getvalue().rsplit("\r", 1)[-1]


class _GrowingSource:
    """Frames of 1000, 2000, 3000, ... bytes."""

    kind = "test frames"
    count = 5

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        for i in range(self.count):
            yield SourceFrame(bytes(1000 * (i + 1)), b"\x80", epoch_ns + i)


def test_main_stops_before_a_frame_over_max_frame_bytes(endpoint: str) -> None:
    options = ReplayOptions(key="replay/test", pacing=Pacing.ASAP, max_frame_bytes=2500)
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "replay/test")
        conf = loopback_config(connect=[endpoint])
        with pytest.raises(ReplayError, match=r"frame 3 of the test frames is 3000 bytes"):
            main(conf, _GrowingSource(), options, threading.Event())
        got = [len(frames.get().payload) for _ in range(2)]
        assert got == [1000, 2000]
        assert frames.drain() == []


def test_main_returns_when_stopped_while_waiting_for_a_subscriber() -> None:
    stop = threading.Event()
    stop.set()
    options = ReplayOptions(key="replay/nobody", pacing=Pacing.ASAP)
    assert main(loopback_config(), _ListSource(3), options, stop) == 0


def test_main_times_out_without_a_subscriber() -> None:
    options = ReplayOptions(key="replay/nobody", subscriber_timeout_s=0.2)
    with pytest.raises(ReplayError, match="no subscriber on 'replay/nobody'"):
        main(loopback_config(), _ListSource(3), options, threading.Event())


# -- CLI behaviour ----------------------------------------------------------------------------


def test_cli_image_folder_loop_limit_as_fast_as_possible(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    expected = _write_images(folder)
    with open_session(listen=[endpoint]) as camera_side:
        frames = Collector(camera_side, "zed/left/image")
        args = _replay_args(folder, endpoint, "--loop", "--limit", "25", "--as-fast-as-possible")
        with running_cli(*args) as proc:
            got = [frames.get(timeout=REPLAY_TIMEOUT_S) for _ in range(25)]
            _finish(proc)
        assert frames.drain() == []
    for n, sample in enumerate(got):
        decoded = decode_raw_frame(sample.payload, sample.attachment)
        assert decoded.seq == n  # numbering continues across passes
        np.testing.assert_array_equal(decoded.pixels[:, :, :3], expected[n % N_FRAMES])


def test_cli_waits_for_a_subscriber_so_nothing_is_missed(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    _write_images(folder)
    with open_session(listen=[endpoint]) as camera_side:
        args = _replay_args(folder, endpoint, "--as-fast-as-possible")
        with running_cli(*args) as proc:
            lines = _Lines(proc)
            lines.wait_for("event=replay_waiting")
            frames = Collector(camera_side, "zed/left/image")
            got = [frames.get(timeout=REPLAY_TIMEOUT_S) for _ in range(N_FRAMES)]
            assert proc.wait(timeout=REPLAY_TIMEOUT_S) == 0
        assert [decode_attachment(s.attachment).seq for s in got] == list(range(N_FRAMES))


def test_cli_gives_up_without_a_subscriber(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    _write_images(folder)
    args = ["replay", str(folder), "--no-multicast-scouting", "--subscriber-timeout", "0.3"]
    with running_cli(*args) as proc:
        output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 2
    assert "no subscriber on 'zed/left/image'" in output


def test_cli_refuses_frames_over_max_frame_bytes(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    _write_images(folder)  # 320 x 180 BGRA: 230400 bytes a frame
    with open_session(listen=[endpoint]) as camera_side:
        frames = Collector(camera_side, "zed/left/image")
        args = _replay_args(folder, endpoint, "--max-frame-bytes", "100000")
        with running_cli(*args) as proc:
            output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
        assert frames.drain() == []
    assert proc.returncode == 2, output
    assert "Traceback" not in output
    assert "frame 1 of the images is 230400 bytes, over max_frame_bytes = 100000" in output
    assert "--max-frame-bytes" in output and "transport/link/rx/max_message_size" in output


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_cli_stops_cleanly_on_signals(
    tmp_path: Path, endpoint: str, signum: signal.Signals
) -> None:
    folder = tmp_path / "images"
    _write_images(folder)
    with open_session(listen=[endpoint]) as camera_side:
        frames = Collector(camera_side, "zed/left/image")
        with running_cli(*_replay_args(folder, endpoint, "--loop", "--rate", "50")) as proc:
            for _ in range(3):
                frames.get(timeout=REPLAY_TIMEOUT_S)
            proc.send_signal(signum)
            output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 0, output
    assert f"event=signal signal={signum.name}" in output
    assert "event=replay_done" in output


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["/nonexistent/bag"], "no such file or folder"),
        (["BAG", "--topic", "/missing"], "no topic '/missing'"),
    ],
)
def test_cli_reports_source_errors(tmp_path: Path, args: list[str], match: str) -> None:
    bag = tmp_path / "bag"
    _write_bag(bag, StoragePlugin.MCAP)
    argv = ["replay", *[str(bag) if a == "BAG" else a for a in args], "--no-multicast-scouting"]
    with running_cli(*argv) as proc:
        output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 2
    assert match in output
