"""Faults around the service, with in-process Zenoh routers (zenoh-python in ``mode: router``).

- The real CLI in client mode survives its router being closed and reopened on the same port
  and resumes by itself (Zenoh 1.x clients reconnect with the default ``connect/retry``
  back-off, 1 s doubling to 4 s; nothing to configure).
- A camera that disappears (session closed, even in the middle of a burst) and comes back as a
  new session is answered again.
- A detector error on one frame (OpenCV raises cv2.error) is counted as a rejection
  (``processing_error``) and the worker goes on answering frames.
- SIGTERM while the worker is busy with an HD2K frame stream exits 0 within 2 s.
- SIGTERM or SIGINT while a thread of the process is inside OpenCV (as the worker or a read
  the watchdog abandoned may be) exits 0 within 2 s, for every long-running command: the
  process ends without finalizing the interpreter under that thread.
- A client waiting for its router logs the retries at most once per ``log_interval_s``.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest
import zenoh

from tests.helpers import (
    REPO,
    Collector,
    OutputLines,
    log_events,
    loopback_config,
    loopback_endpoint,
    open_session,
    query_status,
    running_cli,
    sigterm_exit,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tools.rig import MarkerFrame, marker_frame, raw_attachment
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.service import session as service_module
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception.wire.records import TagCodec, decode_record

FRAMES = "zed/left/image"
# Test cameras block rather than let Zenoh drop a large frame when the machine is busy (with
# the default DROP, a frame that cannot be queued within 1 ms is lost).
_BLOCK = zenoh.CongestionControl.BLOCK
_RECONNECT_TIMEOUT = 30.0  # the client retries every 1 s, then 2 s, then 4 s


class Router:
    """An in-process Zenoh router on one loopback port, which a test can restart."""

    def __init__(self, endpoint: str) -> None:
        self.endpoint = endpoint
        self.session: zenoh.Session | None = zenoh.open(
            loopback_config(mode="router", listen=[endpoint])
        )

    def stop(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None

    def start(self) -> zenoh.Session:
        self.stop()
        self.session = zenoh.open(loopback_config(mode="router", listen=[self.endpoint]))
        return self.session


@pytest.fixture
def router() -> Iterator[Router]:
    router = Router(loopback_endpoint())
    try:
        yield router
    finally:
        router.stop()


def _frame(tag_id: int) -> MarkerFrame:
    return marker_frame(320, 240, tag_id, side=96, origin=(60, 50))


def _record_among(records: Collector, seqs: list[int]) -> dict[str, Any]:
    """The next record of one of ``seqs``; queue.Empty when none comes within 2 s."""
    while True:
        record = decode_record(records.get(timeout=2.0).payload)
        if record["seq"] in seqs:
            return record


def _answered(session: zenoh.Session, tag_id: int, seq: int) -> dict[str, Any]:
    """Publish a frame through ``session`` until the service answers it; return the record.

    A frame is re-sent (new seq) when no answer came within 2 s: what is tested is that the
    service answers again by itself, not that one particular frame survives the restart.
    """
    frame = _frame(tag_id)
    records = Collector(session, "perception/tags")
    tags = Collector(session, "tag")
    publisher = session.declare_publisher(FRAMES, congestion_control=_BLOCK)
    try:
        wait_for_subscriber(publisher, timeout=_RECONNECT_TIMEOUT)
        deadline = time.monotonic() + _RECONNECT_TIMEOUT
        sent: list[int] = []
        while time.monotonic() < deadline:
            sent.append(seq + 1000 * len(sent))
            publisher.put(frame.payload, attachment=raw_attachment(320, 240, seq=sent[-1]))
            try:
                record = _record_among(records, sent)
            except queue.Empty:
                continue
            assert TagCodec().decode(tags.get(timeout=10.0).payload).tag_id == tag_id
            return record
        pytest.fail(f"frames {sent} not answered; status {query_status(session, timeout=2.0)}")
    finally:
        publisher.undeclare()
        records.undeclare()
        tags.undeclare()


def test_client_mode_service_resumes_after_its_router_restarts(router: Router) -> None:
    args = ("run", "-m", "client", "-e", router.endpoint, "--no-multicast-scouting")
    with running_cli(*args, "--stats-interval-s", "0") as proc:
        assert router.session is not None
        zid = wait_for_status(router.session)["zid"]
        assert _answered(router.session, 4, seq=1)["selected"] == {
            "tag_id": 4,
            "x_tag_center_pixel": 107.5,
            "y_tag_center_pixel": 97.5,
            "closeness_metric": pytest.approx(1 - (96 * 96 / (320 * 240)) ** 0.5, abs=0.01),
        }
        session = router.session

        def processed() -> int:
            status = query_status(session)
            return -1 if status is None else int(status["frames"]["processed"])

        for restart in range(2):

            def counted(n: int = 1 + restart) -> bool:
                return processed() >= n  # (a frame re-sent by _answered may count too)

            # a frame is counted once its record is out: wait for the count, do not race it
            wait_until(counted, what=f"{1 + restart} frames counted")
            router.stop()
            session = router.start()
            # The same service process (same Zenoh id) comes back on its own: status, frames.
            status = wait_for_status(session, timeout=_RECONNECT_TIMEOUT)
            assert status["zid"] == zid
            assert status["frames"]["processed"] >= 1 + restart
            # Same tag, new seq: the record of this very frame must come back.
            record = _answered(session, 4, seq=2 + restart)
            assert record["selected"]["tag_id"] == 4
        assert proc.poll() is None


def _settled(service: PerceptionService, processed: int) -> dict[str, int]:
    """The frame counters once ``processed`` frames are counted and nothing is in flight.

    The service publishes a frame's tag and record before counting it as processed.
    """

    def frames() -> dict[str, int]:
        counters: dict[str, int] = service.status()["frames"]
        return counters

    def settled() -> bool:
        f = frames()
        done = f["processed"] + f["dropped"] + f["rejected"]
        return f["processed"] >= processed and f["received"] == done

    wait_until(settled, what=f"{processed} frames processed and nothing in flight")
    return frames()


def test_camera_leaving_and_coming_back_is_answered_again(router: Router) -> None:
    assert router.session is not None
    observer = router.session
    with (
        open_session(mode="client", connect=[router.endpoint]) as service_session,
        PerceptionService(service_session, Settings.from_flat(stats_interval_s=0.0)) as service,
    ):
        records = Collector(observer, "perception/tags")
        # First camera: a burst, then it vanishes in the middle of it (session closed).
        frame = _frame(6)
        with open_session(mode="client", connect=[router.endpoint]) as camera:
            publisher = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
            wait_for_subscriber(publisher)
            for seq in range(30):
                publisher.put(frame.payload, attachment=raw_attachment(320, 240, seq=seq))
            first = decode_record(records.get(timeout=10.0).payload)
        assert first["selected"]["tag_id"] == 6
        # A new camera session (new Zenoh id) is answered like the first.
        with open_session(mode="client", connect=[router.endpoint]) as camera:
            record = _answered(camera, 6, seq=100)
        assert record["selected"]["tag_id"] == 6
        frames = _settled(service, processed=2)
        assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]


class _FailingOn(Detector):
    """The real detector, except that it raises cv2.error (as OpenCV does) on one frame width."""

    def __init__(self, width: int) -> None:
        self._inner = make_detector("tracking", "DICT_4X4_50")
        self._width = width

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        if gray.shape[1] == self._width:
            msg = "simulated detector failure"
            raise cv2.error(msg)
        return self._inner.detect(gray)


def test_a_detector_error_on_one_frame_is_counted_and_the_worker_goes_on(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    service_session, camera = peers
    settings = Settings.from_flat(stats_interval_s=0.0)
    with PerceptionService(service_session, settings, detector=_FailingOn(17)) as service:
        publisher = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        publisher.put(b"\x80" * 17 * 5, attachment=raw_attachment(17, 5, seq=1, encoding="mono8"))
        wait_until(
            lambda: service.status()["rejected_by_reason"].get("processing_error") == 1,
            what="the failed frame counted",
        )
        publisher.undeclare()
        record = _answered(camera, 3, seq=2)
        frames = _settled(service, processed=1)
    assert record["selected"]["tag_id"] == 3
    assert frames["rejected"] == 1
    assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]


class _Stream:
    """Publishes one frame over and over from a thread until stopped (Zenoh drops if full)."""

    def __init__(self, session: zenoh.Session, frame: MarkerFrame) -> None:
        self._publisher = session.declare_publisher(
            FRAMES, congestion_control=zenoh.CongestionControl.DROP
        )
        self._frame = frame
        self._stop = threading.Event()
        self.sent = 0
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        wait_for_subscriber(self._publisher)
        self._thread.start()

    def _run(self) -> None:
        frame = self._frame
        while not self._stop.is_set():
            attachment = raw_attachment(frame.width, frame.height, seq=self.sent)
            self._publisher.put(frame.payload, attachment=attachment)
            self.sent += 1
            self._stop.wait(0.005)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._publisher.undeclare()


def _busy(status: dict[str, Any] | None) -> bool:
    return (
        status is not None
        and status["frames"]["processed"] >= 3
        and status["frames"]["dropped"] >= 1
    )


def test_sigterm_during_an_hd2k_stream_exits_0_within_2_seconds(router: Router) -> None:
    assert router.session is not None
    width, height = RESOLUTIONS["HD2K"]
    frame = marker_frame(width, height, 2, clutter=True)
    args = ("run", "-m", "client", "-e", router.endpoint, "--no-multicast-scouting")
    session = router.session
    with running_cli(*args, "--stats-interval-s", "0") as proc:
        wait_for_status(session)
        stream = _Stream(session, frame)
        stream.start()
        try:
            # The worker is busy: frames keep coming faster than it processes them.
            wait_until(
                lambda: _busy(query_status(session, timeout=1.0)),
                timeout=60.0,
                what="the service processing and dropping frames",
            )
            code, elapsed = sigterm_exit(proc)
        finally:
            stream.stop()
        output = proc.stdout.read() if proc.stdout is not None else ""
    assert code == 0, output
    assert elapsed < 2.0, f"exit took {elapsed:.2f} s"
    assert [e["signal"] for e in log_events(output, "signal")] == ["SIGTERM"]
    (stopped,) = log_events(output, "stopped")
    assert int(stopped["processed"]) >= 3 and int(stopped["dropped"]) >= 1
    assert "Traceback" not in output


def test_client_mode_waits_for_a_router_that_is_not_up_yet(endpoint: str) -> None:
    """A client started before its router retries instead of dying, then serves frames."""
    with running_cli("run", "-m", "client", "-e", endpoint, "--no-multicast-scouting") as proc:
        # The service is up and retrying before any router listens on the endpoint.
        OutputLines(proc).wait_for("event=connect_failed")
        with open_session(mode="router", listen=[endpoint]) as router:
            status = wait_for_status(router)
            assert status["worker_alive"] is True
        assert proc.poll() is None
    assert proc.returncode == 0


def test_connection_retries_are_logged_at_most_once_per_interval(
    endpoint: str, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Every retry of a client whose router is down is one log line without the rate limit."""
    caplog.set_level(logging.WARNING, logger="zenoh_perception")
    attempts: list[int] = []

    def refuse(_conf: zenoh.Config) -> zenoh.Session:
        attempts.append(1)
        msg = "simulated: no router"
        raise zenoh.ZError(msg)

    monkeypatch.setattr(zenoh, "open", refuse)
    stop = threading.Event()
    results: list[zenoh.Session | None] = []
    conf = loopback_config(mode="client", connect=[endpoint])
    waiter = threading.Thread(
        target=lambda: results.append(
            service_module.open_session(conf, stop, retry_s=0.01, log_interval_s=60)
        )
    )
    waiter.start()
    try:
        wait_until(lambda: len(attempts) >= 10, what="ten connection attempts")
    finally:
        stop.set()
        waiter.join(timeout=10)
    assert results == [None]
    lines = [r.getMessage() for r in caplog.records if "event=connect_failed" in r.getMessage()]
    assert len(lines) == 1, lines
    assert "simulated: no router" in lines[0]


# The real command line, in a process one of whose threads stays inside OpenCV, coming back for
# the GIL between calls, as the service's worker or a read the watchdog abandoned does. Were the
# interpreter finalized under it, that thread would be unwound by force through OpenCV's
# catch-all C++ code: SIGABRT ("terminate called without an active exception"), every time.
_CLI_WITH_A_THREAD_IN_OPENCV = """
import sys, threading
import cv2
import numpy as np

y, x = np.indices((720, 1280))
board = np.asarray(((x // 10 + y // 10) % 2) * 255, dtype=np.uint8)

def busy():
    while True:
        cv2.GaussianBlur(board, (31, 31), 0)

threading.Thread(target=busy, daemon=True).start()
from zenoh_perception.cli.main import main
sys.exit(main())
"""


@contextmanager
def _cli_with_a_thread_in_opencv(*args: str) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen(
        [sys.executable, "-c", _CLI_WITH_A_THREAD_IN_OPENCV, *args],
        cwd=REPO,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def _serving(session: zenoh.Session) -> None:
    wait_for_status(session)


def _subscribed(key: str) -> Callable[[zenoh.Session], None]:
    def ready(session: zenoh.Session) -> None:
        publisher = session.declare_publisher(key)
        try:
            wait_for_subscriber(publisher, timeout=60.0)
        finally:
            publisher.undeclare()

    return ready


def _publishing(session: zenoh.Session) -> None:
    frames = Collector(session, FRAMES)
    try:
        frames.get(timeout=60.0)
    finally:
        frames.undeclare()


#: Each long-running command's arguments, and what says it is up (its signal handlers set).
_COMMANDS: dict[str, tuple[tuple[str, ...], Callable[[zenoh.Session], None]]] = {
    "run": (("run", "--stats-interval-s", "0"), _serving),
    "demo": (("demo", "--stats-interval-s", "0", "--resolution", "HD720"), _serving),
    "echo": (("echo",), _subscribed("tag")),
    "view": (
        ("view", "--save", "{tmp}/latest.jpg"),
        _subscribed(Settings().outputs.debug_image_key),
    ),
    "replay": (("replay", "{tmp}/frame.png", "--loop", "--rate", "20"), _publishing),
}


@pytest.mark.parametrize(
    ("command", "signum"),
    [
        ("run", signal.SIGTERM),
        ("run", signal.SIGINT),
        ("demo", signal.SIGTERM),
        ("demo", signal.SIGINT),
        ("echo", signal.SIGTERM),
        ("view", signal.SIGTERM),
        ("replay", signal.SIGTERM),
    ],
    ids=lambda value: value.name if isinstance(value, signal.Signals) else value,
)
def test_a_signal_exits_0_within_2_seconds_while_a_thread_is_inside_opencv(
    router: Router, tmp_path: Path, command: str, signum: signal.Signals
) -> None:
    assert router.session is not None
    cv2.imwrite(str(tmp_path / "frame.png"), np.full((240, 320, 3), 255, np.uint8))
    args, ready = _COMMANDS[command]
    zenoh_flags = ("-m", "client", "-e", router.endpoint, "--no-multicast-scouting")
    argv = [a.format(tmp=tmp_path) for a in args]
    with _cli_with_a_thread_in_opencv(*argv, *zenoh_flags) as proc:
        ready(router.session)
        started = time.monotonic()
        proc.send_signal(signum)
        try:
            code = proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            pytest.fail(f"no exit within 10 s of {signum.name}")
        elapsed = time.monotonic() - started
        output = proc.stdout.read() if proc.stdout is not None else ""
    assert code == 0, output
    assert elapsed < 2.0, f"exit took {elapsed:.2f} s"
    assert [e["signal"] for e in log_events(output, "signal")] == [signum.name]
    if command in ("run", "demo"):
        assert len(log_events(output, "stopped")) == 1  # the service closed first
    assert "terminate called" not in output and "Traceback" not in output
