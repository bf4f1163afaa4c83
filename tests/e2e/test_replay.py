"""``zenoh-perception replay`` end to end: the real CLI replays bags, videos and image folders
into a running :class:`PerceptionService`, and every answered frame carries its ORIGINAL header
stamp."""

from __future__ import annotations

import queue
import signal
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from rosbags.rosbag2 import StoragePlugin

from tests.camera.recordings import (
    FRAME_ID,
    HEADER_STAMPS,
    N_FRAMES,
    TAG_IDS,
    H,
    W,
    write_bag,
    write_images,
    write_video,
)
from tests.helpers import (
    STREAMS,
    Collector,
    OutputLines,
    log_events,
    open_session,
    parse_pairs,
    running_cli,
    wait_until,
)
from zenoh_perception.camera.shm import DEFAULT_SLOTS
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception.wire.compressed import compressed_image_data, decode_compressed_cdr
from zenoh_perception.wire.frames import (
    decode_attachment,
    decode_raw_frame,
)
from zenoh_perception.wire.records import decode_record

REPLAY_TIMEOUT_S = 60.0


@dataclass
class Served:
    """A peer listening on the test's endpoint, with a started in-process service."""

    session: zenoh.Session
    service: PerceptionService

    def answered(self, records: Collector, sent: int) -> list[dict[str, Any]]:
        """The records of the frames the service answered, once each of the ``sent`` frames is
        accounted for (answered, or dropped by the latest-frame-wins mailbox).

        On a busy machine the replay may outrun the worker: the mailbox then drops a frame
        (counted) and only the newest is answered. The last frame is never dropped.
        """

        def settled() -> bool:
            frames: dict[str, int] = self.service.status()["frames"]
            done = frames["processed"] + frames["dropped"] + frames["rejected"]
            return frames["received"] == sent and done == sent

        wait_until(settled, timeout=REPLAY_TIMEOUT_S, what=f"all {sent} frames accounted for")
        frames = self.service.status()["frames"]
        assert frames["rejected"] == 0
        got = [
            decode_record(records.get(timeout=REPLAY_TIMEOUT_S).payload)
            for _ in range(frames["processed"])
        ]
        assert records.drain() == []
        assert len(got) + frames["dropped"] == sent
        return got


@pytest.fixture
def served(endpoint: str) -> Iterator[Served]:
    with (
        open_session(listen=[endpoint]) as session,
        PerceptionService(session, Settings.from_flat(stats_interval_s=0.0)) as service,
    ):
        yield Served(session, service)


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


def _done(output: str) -> dict[str, str]:
    """The fields of the replay's ``event=replay_done`` line."""
    (done,) = log_events(output, "replay_done")
    return done


def _frame_indices(got: list[dict[str, Any]], key: str, values: list[int]) -> list[int]:
    """Which frame (by its position in ``values``) each record answers; strictly increasing
    (records come in order, dropped frames leave gaps) and ending with the last frame."""
    indices = [values.index(record[key]) for record in got]
    assert indices == sorted(set(indices)), indices
    assert indices[-1] == len(values) - 1  # the newest frame is never dropped
    return indices


@pytest.mark.parametrize("plugin", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_bag_replays_through_the_service_with_original_stamps(
    tmp_path: Path, endpoint: str, served: Served, plugin: StoragePlugin
) -> None:
    bag = tmp_path / "bag"
    write_bag(bag, plugin)
    records = Collector(served.session, "perception/tags")
    with running_cli(*_replay_args(bag, endpoint)) as proc:
        output = _finish(proc)
    assert _done(output)["published"] == str(N_FRAMES)
    got = served.answered(records, N_FRAMES)
    # each record carries the header stamp of the frame it answers, and that frame's tag
    indices = _frame_indices(got, "stamp_ns", HEADER_STAMPS)
    assert [r["selected"]["tag_id"] for r in got] == [TAG_IDS[i] for i in indices]
    assert {r["source"] for r in got} == {"cdr"}
    assert {r["frame_id"] for r in got} == {FRAME_ID}
    assert {(r["width"], r["height"]) for r in got} == {(W, H)}


def test_video_replays_through_the_service_with_seq_and_stamps(
    tmp_path: Path, endpoint: str, served: Served
) -> None:
    video = tmp_path / "drive.avi"
    write_video(video, fps=20.0)
    records = Collector(served.session, "perception/tags")
    with running_cli(*_replay_args(video, endpoint, "--frame-id", "cam0")) as proc:
        output = _finish(proc)
    assert _done(output)["published"] == str(N_FRAMES)
    got = served.answered(records, N_FRAMES)
    seqs = _frame_indices(got, "seq", list(range(N_FRAMES)))
    assert [r["selected"]["tag_id"] for r in got] == [TAG_IDS[i] for i in seqs]
    assert {r["source"] for r in got} == {"raw"}
    assert {r["frame_id"] for r in got} == {"cam0"}
    # Stamps follow the video's clock: 20 fps -> exactly 50 ms per frame.
    first = got[0]
    assert [r["stamp_ns"] - first["stamp_ns"] for r in got] == [
        (seq - seqs[0]) * 50_000_000 for seq in seqs
    ]


@pytest.mark.parametrize("kind", ["video", "bag"])
def test_shm_replay_is_answered_and_read_from_shared_memory(
    tmp_path: Path, endpoint: str, served: Served, kind: str
) -> None:
    """``--shm``: raw frames (video) and CDR frames (bag) go from shared memory, the service
    answers them, and on this machine the service side reads every one in place. (Plain puts
    of large frames also arrive in shared memory once Zenoh's transport optimisation has copied
    them there, all but the first frames here: the replay's own counters tell the paths apart.)

    On a busy machine the service and Zenoh may still hold every buffer of the replay's pool
    when a frame comes: that frame goes as plain bytes, counted, and the replay never waits.
    A fresh pool has a buffer for each of its first frames.
    """
    if kind == "video":
        source = tmp_path / "drive.avi"
        write_video(source, fps=20.0)
    else:
        source = tmp_path / "bag"
        write_bag(source, StoragePlugin.MCAP)
    in_shm: queue.Queue[bool] = queue.Queue()
    frames = served.session.declare_subscriber(
        "zed/left/image", lambda sample: in_shm.put(sample.payload.as_shm() is not None)
    )
    records = Collector(served.session, "perception/tags")
    try:
        with running_cli(*_replay_args(source, endpoint, "--shm", "--rate", "10")) as proc:
            output = _finish(proc)
        shm = [in_shm.get(timeout=REPLAY_TIMEOUT_S) for _ in range(N_FRAMES)]
    finally:
        frames.undeclare()
    got = served.answered(records, N_FRAMES)
    if kind == "video":
        indices = _frame_indices(got, "seq", list(range(N_FRAMES)))
    else:
        indices = _frame_indices(got, "stamp_ns", HEADER_STAMPS)
    assert [r["selected"]["tag_id"] for r in got] == [TAG_IDS[i] for i in indices]
    assert {r["source"] for r in got} == {"raw" if kind == "video" else "cdr"}
    (started,) = log_events(output, "replay_started")
    assert started["shm"] == "True"
    done = _done(output)
    shm_frames, plain_frames = int(done["shm_frames"]), int(done["plain_frames"])
    assert shm_frames + plain_frames == N_FRAMES
    assert shm_frames >= DEFAULT_SLOTS
    assert sum(shm) >= shm_frames, (shm, done)  # each frame put from shared memory read in place


@pytest.mark.parametrize("codec", ["jpeg", "png"])
def test_bag_replays_compressed_through_the_service_with_original_stamps(
    tmp_path: Path, endpoint: str, served: Served, codec: str
) -> None:
    bag = tmp_path / "bag"
    write_bag(bag, StoragePlugin.MCAP)
    records = Collector(served.session, "perception/tags")
    raw = Collector(served.session, "zed/left/image")
    with running_cli(*_replay_args(bag, endpoint, "--compressed", codec)) as proc:
        output = _finish(proc)
    (started,) = log_events(output, "replay_started")
    assert (started["key"], started["compressed"]) == ("zed/left/image/compressed", codec)
    got = served.answered(records, N_FRAMES)
    indices = _frame_indices(got, "stamp_ns", HEADER_STAMPS)
    assert [r["selected"]["tag_id"] for r in got] == [TAG_IDS[i] for i in indices]
    assert {r["source"] for r in got} == {"compressed"}
    assert {r["frame_id"] for r in got} == {FRAME_ID}
    assert {(r["width"], r["height"]) for r in got} == {(W, H)}
    assert raw.drain() == []  # nothing on the raw key


def test_cli_image_folder_replays_compressed_frames_as_image_transport_does(
    tmp_path: Path, endpoint: str
) -> None:
    folder = tmp_path / "images"
    expected = write_images(folder)
    with open_session(listen=[endpoint]) as camera_side:
        frames = Collector(camera_side, "zed/left/image/compressed")
        args = _replay_args(
            folder, endpoint, "--as-fast-as-possible", "--compressed", "png", "--frame-id", "c0"
        )
        with running_cli(*args) as proc:
            got = [frames.get(timeout=REPLAY_TIMEOUT_S) for _ in range(N_FRAMES)]
            _finish(proc)
    for n, sample in enumerate(got):
        fmt, _ = compressed_image_data(sample.payload)
        assert fmt == "bgra8; png compressed bgr8"
        decoded = decode_compressed_cdr(sample.payload)
        assert decoded.frame_id == "c0"
        np.testing.assert_array_equal(decoded.pixels, expected[n])  # PNG: lossless


def test_cli_image_folder_loop_limit_as_fast_as_possible(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    expected = write_images(folder)
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
    write_images(folder)
    with open_session(listen=[endpoint]) as camera_side:
        args = _replay_args(folder, endpoint, "--as-fast-as-possible")
        with running_cli(*args) as proc:
            lines = OutputLines(proc)
            lines.wait_for("event=replay_waiting")
            frames = Collector(camera_side, "zed/left/image")
            got = [frames.get(timeout=REPLAY_TIMEOUT_S) for _ in range(N_FRAMES)]
            assert proc.wait(timeout=REPLAY_TIMEOUT_S) == 0
        assert [decode_attachment(s.attachment).seq for s in got] == list(range(N_FRAMES))


def test_cli_gives_up_without_a_subscriber(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    args = ["replay", str(folder), "--no-multicast-scouting", "--subscriber-timeout", "0.3"]
    with running_cli(*args) as proc:
        output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 2
    assert "no subscriber on 'zed/left/image'" in output


def test_cli_refuses_frames_over_max_frame_bytes(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    write_images(folder)  # 320 x 180 BGRA: 230400 bytes a frame
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
    write_images(folder)
    with open_session(listen=[endpoint]) as camera_side:
        frames = Collector(camera_side, "zed/left/image")
        with running_cli(*_replay_args(folder, endpoint, "--loop", "--rate", "50")) as proc:
            for _ in range(3):
                frames.get(timeout=REPLAY_TIMEOUT_S)
            proc.send_signal(signum)
            output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 0, output
    assert [e["signal"] for e in log_events(output, "signal")] == [signum.name]
    assert _done(output)["stopped"] == "True"


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["/nonexistent/bag"], "no such file or folder"),
        (["BAG", "--topic", "/missing"], "no topic '/missing'"),
    ],
)
def test_cli_reports_source_errors(tmp_path: Path, args: list[str], match: str) -> None:
    bag = tmp_path / "bag"
    write_bag(bag, StoragePlugin.MCAP)
    argv = ["replay", *[str(bag) if a == "BAG" else a for a in args], "--no-multicast-scouting"]
    with running_cli(*argv) as proc:
        output, _ = proc.communicate(timeout=REPLAY_TIMEOUT_S)
    assert proc.returncode == 2
    assert match in output


def test_cli_image_folder_says_which_files_it_leaves_out(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    (folder / "drive.mp4").write_bytes(b"not an image")
    (folder / "notes.txt").write_text("labels")
    with open_session(listen=[endpoint]) as camera_side:
        frames = Collector(camera_side, "zed/left/image")
        with running_cli(*_replay_args(folder, endpoint, "--as-fast-as-possible")) as proc:
            lines = OutputLines(proc)
            skipped = parse_pairs(lines.wait_for("event=replay_skipped_files"))
            got = [frames.get(timeout=REPLAY_TIMEOUT_S) for _ in range(N_FRAMES)]
            assert proc.wait(timeout=REPLAY_TIMEOUT_S) == 0
    assert skipped["count"] == "2" and skipped["files"] == "drive.mp4,notes.txt"
    assert len(got) == N_FRAMES  # the images are replayed all the same


def test_a_camera_nobody_reads_is_told_what_the_services_read(
    tmp_path: Path, endpoint: str
) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    settings = STREAMS.with_flat(input_key="rover/*/image")
    with (
        open_session(listen=[endpoint]) as service_side,
        PerceptionService(service_side, settings),
    ):
        args = _replay_args(folder, endpoint, "--key", "rover/front/camera/image")
        with running_cli(*args) as proc:
            lines = OutputLines(proc)
            for _ in range(2):  # said again while it waits, at a limited rate
                fields = parse_pairs(lines.wait_for("event=replay_waiting", timeout=60))
                assert fields["services"] == "1"
                assert "rover/*/image" in fields["their_inputs"].split(",")
                assert "'*' matches one chunk" in fields["detail"]
            assert proc.poll() is None  # still waiting


def test_a_camera_with_no_service_anywhere_says_so(tmp_path: Path, endpoint: str) -> None:
    folder = tmp_path / "images"
    write_images(folder)
    with running_cli(*_replay_args(folder, endpoint)) as proc:
        fields = parse_pairs(OutputLines(proc).wait_for("event=replay_waiting", timeout=60))
    assert fields["services"] == "0"
    assert "no perception service answered" in fields["detail"]
