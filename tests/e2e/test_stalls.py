"""Frames that stall OpenCV's detector, through the real ``zenoh-perception run`` process.

A checkerboard whose squares sit just above OpenCV's smallest marker (a tiled floor, a
calibration board) takes OpenCV's ArUco detector seconds: the service abandons it at
``frame_deadline_ms``, counts it, and answers the newest frame behind it; SIGTERM during such
a frame still exits at once.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
import pytest
import zenoh

from tests.helpers import (
    Collector,
    OutputLines,
    log_events,
    open_session,
    query_status,
    running_cli,
    sigterm_exit,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tools.rig import marker_frame, raw_attachment
from zenoh_perception.wire.records import TagCodec, decode_record

FRAMES = "zed/left/image"
_BLOCK = zenoh.CongestionControl.BLOCK


def checkerboard(width: int, height: int, square: int) -> npt.NDArray[np.uint8]:
    """Black and white squares of ``square`` px: thousands of candidate quads for OpenCV."""
    y, x = np.indices((height, width))
    return np.asarray(((x // square + y // square) % 2) * 255, dtype=np.uint8)


@pytest.fixture
def camera(endpoint: str) -> Iterator[zenoh.Session]:
    with open_session(mode="router", listen=[endpoint]) as session:
        yield session


def _service(endpoint: str, *flags: str) -> tuple[str, ...]:
    args = ("run", "-m", "client", "-e", endpoint, "--no-multicast-scouting")
    return (*args, "--stats-interval-s", "0.2", *flags)


def _put_board(
    publisher: zenoh.Publisher, session: zenoh.Session, size: tuple[int, int, int]
) -> None:
    """Put a checkerboard frame (seq 1) and wait until the service has received it: the
    worker, idle until then, takes it at once."""
    width, height, square = size
    board = checkerboard(width, height, square)
    publisher.put(
        board.tobytes(), attachment=raw_attachment(width, height, seq=1, encoding="mono8")
    )
    wait_until(
        lambda: (query_status(session) or {}).get("frames", {}).get("received") == 1,
        what="the checkerboard received",
    )


@pytest.mark.parametrize(
    ("size", "process"),
    [
        ((1280, 720, 10), "on_stall"),
        ((1920, 1080, 15), "on_stall"),
        ((4096, 4096, 32), "on_stall"),
        ((1280, 720, 10), "always"),
    ],
    ids=["720p", "1080p", "4096", "720p-child"],
)
def test_a_stalled_frame_is_abandoned_and_the_next_frame_answered(
    endpoint: str, camera: zenoh.Session, size: tuple[int, int, int], process: str
) -> None:
    tags = Collector(camera, "tag")
    records = Collector(camera, "perception/tags")
    with running_cli(*_service(endpoint, "--detector-process", process)) as proc:
        wait_for_status(camera)
        publisher = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        _put_board(publisher, camera, size)
        good = marker_frame(1280, 720, 7, side=160)
        publisher.put(good.payload, attachment=raw_attachment(1280, 720, seq=2))
        record = decode_record(records.get().payload)
        # The board got no record: the first one is the good frame's, with its tag.
        assert record["seq"] == 2
        assert record["selected"]["tag_id"] == 7
        wait_until(
            lambda: (query_status(camera) or {}).get("budget", {}).get("abandoned") == 1,
            what="the checkerboard counted abandoned",
        )
        # the good frame is counted once all its outputs are out, after its record
        expected = {"received": 2, "processed": 1, "dropped": 0, "rejected": 1}
        wait_until(
            lambda: (query_status(camera) or {}).get("frames") == expected,
            what="the good frame counted processed",
        )
        status = query_status(camera)
        assert status is not None
        assert status["rejected_by_reason"] == {"abandoned": 1}
        assert status["frames"] == expected
        budget = status["budget"]
        assert budget["frame_deadline_ms"] == 400.0
        assert budget["abandoned_ms_max"] >= 400.0
        assert status["worker_alive"] is True
        # One tag per answered frame: the good frame's only.
        assert [TagCodec().decode(t.payload).tag_id for t in tags.drain()] == [7]
        stats = OutputLines(proc).wait_for("abandoned=1 ")
        assert "event=stats" in stats
        assert records.drain() == []
    assert proc.returncode == 0


@pytest.mark.parametrize("process", ["on_stall", "always"])
def test_sigterm_during_a_stalled_frame_exits_promptly(
    endpoint: str, camera: zenoh.Session, process: str
) -> None:
    # A deadline far beyond the frame's time: the frame is still running at SIGTERM (in the
    # service's own process with on_stall, in the child with always).
    flags = ("--frame-deadline-ms", "60000", "--detector-process", process)
    with running_cli(*_service(endpoint, *flags)) as proc:
        wait_for_status(camera)
        publisher = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        _put_board(publisher, camera, (4096, 4096, 32))
        code, elapsed = sigterm_exit(proc)
        output = proc.stdout.read() if proc.stdout is not None else ""
    assert code == 0, output
    # A worker thread inside OpenCV is not waited for; nor is a child, which is killed.
    assert elapsed < 1.5, f"exit took {elapsed:.2f} s"
    (stopped,) = log_events(output, "stopped")
    assert int(stopped["processed"]) == 0
    assert "Traceback" not in output


def test_sigterm_while_an_abandoned_thread_still_runs_exits_promptly(
    endpoint: str, camera: zenoh.Session
) -> None:
    # The board is abandoned after 400 ms; its thread stays in OpenCV for seconds after.
    records = Collector(camera, "perception/tags")
    with running_cli(*_service(endpoint)) as proc:
        wait_for_status(camera)
        publisher = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        _put_board(publisher, camera, (4096, 4096, 32))
        good = marker_frame(1280, 720, 7, side=160)
        publisher.put(good.payload, attachment=raw_attachment(1280, 720, seq=2))
        assert decode_record(records.get().payload)["seq"] == 2
        code, elapsed = sigterm_exit(proc)
        output = proc.stdout.read() if proc.stdout is not None else ""
    assert code == 0, output
    assert elapsed < 1.5, f"exit took {elapsed:.2f} s"
    (stopped,) = log_events(output, "stopped")
    assert (stopped["processed"], stopped["rejected"]) == ("1", "1")
    assert "Traceback" not in output
