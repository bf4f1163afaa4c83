"""The service's debug image costs nothing unless watched, and is a valid annotated
CompressedImage if so.

The service runs in process; spies on ``annotate`` and ``encode_compressed_image`` (as the
service module calls them) count how many debug images it actually produced."""

from __future__ import annotations

import queue
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest
import zenoh

from tests.helpers import (
    WAIT_S,
    Collector,
    Received,
    open_session,
    query_status,
    wait_for_subscriber,
    wait_until,
)
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception.wire.debug_image import annotate as real_annotate
from zenoh_perception.wire.debug_image import encode_compressed_image as real_encode
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, TYPESTORE
from zenoh_perception.wire.records import TagCodec, decode_record
from zenoh_perception_bench.scene import render_markers

Pixels = npt.NDArray[np.uint8]


W, H = 640, 480


DEBUG_KEY = "perception/debug/image/compressed"


FRAME_ID = "cam_debug"
_BLOCK = zenoh.CongestionControl.BLOCK


BASE_STAMP = 1_700_000_123_000_000_000


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


#: Two tags: a big one (id 5) and a small one (id 21); the record says which is selected.
FRAME = render_markers(W, H, [(5, _square(60, 120, 200)), (21, _square(420, 160, 110))])


@dataclass
class _Spy:
    annotate: int = 0
    encode: int = 0


@dataclass
class _Rig:
    camera: zenoh.Session
    publisher: zenoh.Publisher
    records: Collector
    tags: Collector
    spy: _Spy
    seq: int = 0

    def send_and_wait(self, stamp_ns: int | None = None) -> dict[str, Any]:
        """Publish one frame (stamped ``stamp_ns``, by default BASE_STAMP + its seq) and
        return its record (its tag arrived too)."""
        self.seq += 1
        stamp = BASE_STAMP + self.seq if stamp_ns is None else stamp_ns
        meta = RawFrameMeta(W, H, "bgra8", stamp_ns=stamp, frame_id=FRAME_ID, seq=self.seq)
        self.publisher.put(FRAME.tobytes(), attachment=meta.to_msgpack())
        record = decode_record(self.records.get().payload)
        assert record["seq"] == self.seq
        TagCodec().decode(self.tags.get().payload)
        return record


@pytest.fixture
def rig(endpoint: str, monkeypatch: pytest.MonkeyPatch) -> Iterator[_Rig]:
    spy = _Spy()

    def annotate(*args: Any, **kwargs: Any) -> Pixels:
        spy.annotate += 1
        return real_annotate(*args, **kwargs)

    def encode(*args: Any, **kwargs: Any) -> memoryview:
        spy.encode += 1
        return real_encode(*args, **kwargs)

    # The service calls these through its module globals: patch them there (a test may patch
    # annotate again to make it fail).
    monkeypatch.setattr("zenoh_perception.service.outputs.annotate", annotate)
    monkeypatch.setattr("zenoh_perception.service.outputs.encode_compressed_image", encode)
    # No rate cap in the way: every watched frame yields a debug image.
    settings = Settings.from_flat(stats_interval_s=0.0, debug_image_max_hz=1000.0)
    with (
        open_session(listen=[endpoint]) as service_side,
        PerceptionService(service_side, settings),
        open_session(connect=[endpoint]) as camera,
    ):
        records = Collector(camera, "perception/tags")
        tags = Collector(camera, "tag")
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        yield _Rig(camera, publisher, records, tags, spy)


def _until_drawn(
    rig: _Rig, viewer: Collector, stamp_ns: int | None = None
) -> tuple[dict[str, Any], Received, int]:
    """Frames until a debug image arrives: its frame's record, the image and the frames sent.

    The debug image is a best-effort view (dropped, not queued, when the link is congested:
    a busy machine may lose one), so a test sends frames until one is seen.
    """
    records: dict[int, dict[str, Any]] = {}
    deadline = time.monotonic() + WAIT_S
    sent = 0
    while True:
        record = rig.send_and_wait(stamp_ns)
        records[min(record["stamp_ns"], ROS_TIME_MAX_NS)] = record
        sent += 1
        try:
            sample = viewer.get(timeout=2.0)
        except queue.Empty:
            if time.monotonic() > deadline:
                raise
            continue
        return records[_stamp_of(sample.payload)], sample, sent


def _wait_watched(session: zenoh.Session, watched: bool, timeout: float = 10.0) -> None:
    """Until the service's status reports ``debug_image.watched == watched``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = query_status(session)
        if status is not None and status["debug_image"]["watched"] is watched:
            return
    pytest.fail(f"debug_image.watched never became {watched}")


def _edge_midpoints(corners: list[list[float]]) -> list[tuple[int, int]]:
    quad = np.asarray(corners)
    mids = (quad + np.roll(quad, -1, axis=0)) / 2.0
    return [(round(x), round(y)) for x, y in mids]


def _is_green(bgr: Pixels, point: tuple[int, int]) -> bool:
    b, g, r = (int(v) for v in bgr[point[1], point[0]])
    return g > 180 and r < 90 and b < 90


def _is_amber(bgr: Pixels, point: tuple[int, int]) -> bool:
    b, g, r = (int(v) for v in bgr[point[1], point[0]])  # drawn as BGR (0, 200, 255)
    return r > 200 and 140 < g < 240 and b < 90


def test_debug_image_only_while_watched(rig: _Rig) -> None:
    # Nobody watches: tags and records flow, no debug image is drawn or encoded.
    for _ in range(3):
        rig.send_and_wait()
    assert (rig.spy.annotate, rig.spy.encode) == (0, 0)
    _wait_watched(rig.camera, watched=False)

    # A viewer subscribes: the next frame yields a CompressedImage on the debug key.
    viewer = Collector(rig.camera, DEBUG_KEY)
    _wait_watched(rig.camera, watched=True)
    record, sample, drawn = _until_drawn(rig, viewer)
    assert (rig.spy.annotate, rig.spy.encode) == (drawn, drawn)
    msg: Any = TYPESTORE.deserialize_cdr(sample.payload, COMPRESSED_IMAGE_TYPE)
    assert msg.format == "jpeg"
    assert msg.header.frame_id == FRAME_ID
    stamp = msg.header.stamp
    assert stamp.sec * 1_000_000_000 + stamp.nanosec == record["stamp_ns"]
    decoded = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
    assert decoded is not None
    image = np.asarray(decoded, dtype=np.uint8)
    assert image.shape == (H, W, 3)

    # The annotation: the selected tag outlined in green, the other one in amber; the same
    # points are black or white in the camera frame itself.
    tags = {tag["tag_id"]: tag for tag in record["tags"]}
    assert set(tags) == {5, 21}
    selected = record["selected"]["tag_id"]
    (other,) = set(tags) - {selected}
    original = FRAME[:, :, :3]
    for point in _edge_midpoints(tags[selected]["corners"]):
        assert _is_green(image, point), point
        assert not _is_green(original, point)
    for point in _edge_midpoints(tags[other]["corners"]):
        assert _is_amber(image, point), point
        assert not _is_amber(original, point)

    # The viewer leaves: production stops again while tags keep flowing.
    viewer.undeclare()
    _wait_watched(rig.camera, watched=False)
    for _ in range(3):
        rig.send_and_wait()
    assert (rig.spy.annotate, rig.spy.encode) == (drawn, drawn)
    status = query_status(rig.camera)
    assert status is not None
    assert status["debug_image"] == {"watched": False, "published": drawn}


def test_debug_image_is_off_when_disabled(endpoint: str, monkeypatch: pytest.MonkeyPatch) -> None:
    encoded: list[int] = []

    def encode(*args: Any, **kwargs: Any) -> memoryview:
        encoded.append(1)
        return real_encode(*args, **kwargs)

    monkeypatch.setattr("zenoh_perception.service.outputs.encode_compressed_image", encode)
    settings = Settings.from_flat(stats_interval_s=0.0, debug_image=False)
    with (
        open_session(listen=[endpoint]) as service_side,
        PerceptionService(service_side, settings),
        open_session(connect=[endpoint]) as camera,
    ):
        records = Collector(camera, "perception/tags")
        viewer = Collector(camera, DEBUG_KEY)
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        meta = RawFrameMeta(W, H, "bgra8", stamp_ns=BASE_STAMP, frame_id=FRAME_ID, seq=1)
        publisher.put(FRAME.tobytes(), attachment=meta.to_msgpack())
        assert decode_record(records.get().payload)["seq"] == 1
        status = query_status(camera)
        assert status is not None
        assert status["debug_image"] == {"watched": False, "published": 0}
        assert viewer.drain() == []
    assert encoded == []


def _stamp_of(sample_payload: bytes) -> int:
    msg: Any = TYPESTORE.deserialize_cdr(sample_payload, COMPRESSED_IMAGE_TYPE)
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


#: The last instant builtin_interfaces/Time (int32 seconds) can hold.
ROS_TIME_MAX_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999


def test_a_raw_frame_stamped_after_2038_gets_its_debug_image(rig: _Rig) -> None:
    """Raw stamps are 64-bit; the debug image's ROS header holds int32 seconds: clamped."""
    viewer = Collector(rig.camera, DEBUG_KEY)
    _wait_watched(rig.camera, watched=True)
    record, sample, _ = _until_drawn(rig, viewer, stamp_ns=2**62)
    assert record["stamp_ns"] == 2**62  # the record keeps the frame's own stamp
    assert _stamp_of(sample.payload) == ROS_TIME_MAX_NS
    status = query_status(rig.camera)
    assert status is not None and status["worker_alive"] is True


def test_a_failing_debug_image_is_a_counted_processing_error_not_a_dead_worker(
    rig: _Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    failures: list[int] = []

    def annotate_failing_once(*args: Any, **kwargs: Any) -> Pixels:
        if not failures:
            failures.append(1)
            msg = "simulated drawing failure"
            raise cv2.error(msg)
        return real_annotate(*args, **kwargs)

    monkeypatch.setattr("zenoh_perception.service.outputs.annotate", annotate_failing_once)
    viewer = Collector(rig.camera, DEBUG_KEY)
    _wait_watched(rig.camera, watched=True)
    rig.send_and_wait()  # its tag and record are out before the debug image fails

    def processing_errors() -> dict[str, int]:
        status = query_status(rig.camera)
        return {} if status is None else dict(status["processing_errors"])

    wait_until(lambda: processing_errors() == {"debug_image": 1}, what="the failure counted")
    # the worker goes on, and draws the next ones
    record, sample, drawn = _until_drawn(rig, viewer)
    assert _stamp_of(sample.payload) == record["stamp_ns"]
    # the image is counted once it is out: wait for the count, do not race it
    wait_until(
        lambda: (query_status(rig.camera) or {})["debug_image"]["published"] == drawn,
        what="the debug image counted",
    )
    status = query_status(rig.camera)
    assert status is not None
    assert status["worker_alive"] is True
    assert status["frames"]["processed"] == 1 + drawn
    assert status["frames"]["rejected"] == 0  # answered frames are no rejections
    assert status["debug_image"]["published"] == drawn
