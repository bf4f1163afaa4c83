"""The service in-process: real Zenoh peers on loopback, real CDR, real detection."""

from __future__ import annotations

import gc
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest
import zenoh

from tests.helpers import (
    Collector,
    loopback_config,
    open_session,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from zenoh_perception.frames import RawFrameMeta, encode_image_cdr
from zenoh_perception.messages import CAMERA_INFO_TYPE, TYPESTORE
from zenoh_perception.records import TagCodec, decode_record, f32
from zenoh_perception.scene import render_markers
from zenoh_perception.selection import TagMessage
from zenoh_perception.service import PerceptionService, run
from zenoh_perception.settings import Settings

WIDTH, HEIGHT = 640, 480


def square(x0: float, y0: float, side: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


# A big (close) tag 7 and a small (far) tag 3: "closest" must pick 7.
SCENE = render_markers(WIDTH, HEIGHT, [(3, square(420, 60, 60)), (7, square(80, 200, 160))])
EMPTY = render_markers(WIDTH, HEIGHT, [])


@dataclass
class Rig:
    service: PerceptionService
    camera: zenoh.Session
    publisher: zenoh.Publisher
    tags: Collector
    records: Collector

    def put_raw(self, image: np.ndarray, **meta: object) -> None:
        attachment = RawFrameMeta(image.shape[1], image.shape[0], **meta).to_msgpack()  # type: ignore[arg-type]
        self.publisher.put(image.tobytes(), attachment=attachment)

    def put_cdr(self, image: np.ndarray, stamp_ns: int = 0, step: int | None = None) -> None:
        self.publisher.put(
            bytes(encode_image_cdr(image, "bgra8", stamp_ns=stamp_ns, frame_id="zed", step=step))
        )

    def answer(self) -> tuple[TagMessage, dict[str, object]]:
        tag = TagCodec().decode(self.tags.get(timeout=20).payload)
        record = decode_record(self.records.get(timeout=20).payload)
        return tag, record


def _rig(settings: Settings, endpoint: str) -> Iterator[Rig]:
    with (
        open_session(listen=[endpoint]) as service_session,
        open_session(connect=[endpoint]) as camera,
    ):
        service = PerceptionService(service_session, settings)
        service.start()
        try:
            tags = Collector(camera, settings.tag_key)
            records = Collector(camera, settings.record_key)
            publisher = camera.declare_publisher(settings.input_key)
            wait_for_subscriber(publisher)
            yield Rig(service, camera, publisher, tags, records)
        finally:
            service.close()


@pytest.fixture
def rig(endpoint: str) -> Iterator[Rig]:
    yield from _rig(Settings(stats_interval_s=0), endpoint)


def test_raw_and_cdr_frames_each_get_a_tag_and_an_agreeing_record(rig: Rig) -> None:
    for i in range(4):
        if i % 2 == 0:
            rig.put_raw(SCENE, stamp_ns=1000 + i, seq=i, frame_id="zed")
        else:
            rig.put_cdr(SCENE, stamp_ns=2000 + i, step=WIDTH * 4 + 32)
        tag, record = rig.answer()
        assert tag.tag_id == 7
        assert tag.x_tag_center_pixel == pytest.approx(80 + 80, abs=0.75)
        assert tag.y_tag_center_pixel == pytest.approx(200 + 80, abs=0.75)
        assert tag.closeness_metric == pytest.approx(
            1 - np.sqrt(160 * 160 / (WIDTH * HEIGHT)), abs=0.01
        )
        selected = record["selected"]
        assert isinstance(selected, dict)
        assert selected == {
            "tag_id": tag.tag_id,
            "x_tag_center_pixel": tag.x_tag_center_pixel,
            "y_tag_center_pixel": tag.y_tag_center_pixel,
            "closeness_metric": tag.closeness_metric,
        }
        assert sorted(t["tag_id"] for t in record["tags"]) == [3, 7]  # type: ignore[attr-defined]
        assert record["stamp_ns"] == (1000 + i if i % 2 == 0 else 2000 + i)
        assert record["source"] == ("raw" if i % 2 == 0 else "cdr")
        assert (record["width"], record["height"]) == (WIDTH, HEIGHT)


def test_a_frame_without_tags_publishes_the_dummy(rig: Rig) -> None:
    rig.put_raw(EMPTY)
    tag, record = rig.answer()
    assert tag == TagMessage(-1, 0.0, 0.0, 0.0)
    assert record["tags"] == []
    assert record["selected"] == {
        "tag_id": -1,
        "x_tag_center_pixel": 0.0,
        "y_tag_center_pixel": 0.0,
        "closeness_metric": 0.0,
    }


GARBAGE: list[tuple[bytes, bytes | None, str]] = [
    (b"\x00\x01\x00\x00garbage", None, "bad_cdr"),
    (b"", None, "bad_cdr"),
    (bytes(100), b"\xc1\xc1", "bad_attachment"),
    (bytes(100), RawFrameMeta(10, 10, "yuyv").to_msgpack(), "unsupported_encoding"),
    (bytes(100), RawFrameMeta(0, 10).to_msgpack(), "bad_dimensions"),
    (bytes(100), RawFrameMeta(10, 1 << 30).to_msgpack(), "bad_dimensions"),
    (bytes(100), RawFrameMeta(1280, 720).to_msgpack(), "size_mismatch"),
]


def test_garbage_is_rejected_by_reason_and_the_next_good_frame_is_answered(rig: Rig) -> None:
    for count, (payload, attachment, reason) in enumerate(GARBAGE, start=1):
        rig.publisher.put(payload, attachment=attachment)
        wait_until(
            lambda n=count: sum(rig.service.status()["rejected_by_reason"].values()) == n,  # type: ignore[misc]
            what=f"rejection {reason}",
        )
        rig.put_raw(SCENE, seq=1)
        tag, _record = rig.answer()
        assert tag.tag_id == 7
    status = rig.service.status()
    expected: dict[str, int] = {}
    for _payload, _attachment, reason in GARBAGE:
        expected[reason] = expected.get(reason, 0) + 1
    assert status["rejected_by_reason"] == expected
    assert status["frames"]["processed"] == len(GARBAGE)
    assert status["frames"]["received"] == 2 * len(GARBAGE)


def test_closeness_and_record_are_float32_exact(rig: Rig) -> None:
    rig.put_raw(SCENE)
    tag, record = rig.answer()
    for entry in record["tags"]:  # type: ignore[attr-defined]
        assert entry["closeness_metric"] == f32(entry["closeness_metric"])
        corners = np.asarray(entry["corners"])
        assert entry["x_tag_center_pixel"] == pytest.approx(corners[:, 0].mean(), abs=1e-3)
    assert tag.closeness_metric == min(e["closeness_metric"] for e in record["tags"])  # type: ignore[attr-defined]


def test_center_policy_and_custom_keys(endpoint: str) -> None:
    settings = Settings(
        policy="center",
        tag_key="rover/tag",
        record_key="rover/tags",
        input_key="rover/image",
        stats_interval_s=0,
    )
    # Tag 3 sits on the image centre, the bigger tag 7 off to the side.
    image = render_markers(WIDTH, HEIGHT, [(3, square(300, 220, 40)), (7, square(20, 20, 150))])
    for rig in _rig(settings, endpoint):
        rig.put_raw(image)
        tag, _record = rig.answer()
        assert tag.tag_id == 3


def test_camera_info_enables_distance_in_the_record(endpoint: str) -> None:
    settings = Settings(camera_info_key="zed/left/camera_info", tag_size_m=0.2, stats_interval_s=0)
    fx = 500.0
    types = TYPESTORE.types
    info = types[CAMERA_INFO_TYPE](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="zed"
        ),
        height=HEIGHT,
        width=WIDTH,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array([fx, 0, 319.5, 0, fx, 239.5, 0, 0, 1], dtype=np.float64),
        r=np.eye(3).reshape(-1),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )
    for rig in _rig(settings, endpoint):
        info_pub = rig.camera.declare_publisher("zed/left/camera_info")
        wait_for_subscriber(info_pub)
        info_pub.put(bytes(TYPESTORE.serialize_cdr(info, CAMERA_INFO_TYPE)))
        # A 100 px tag of 0.2 m seen fronto-parallel by fx=500 is 1.0 m away.
        image = render_markers(WIDTH, HEIGHT, [(5, square(269.5, 189.5, 100))])
        deadline_tries = 50
        distance = None
        for _ in range(deadline_tries):  # CameraInfo and frames travel independently
            rig.put_raw(image)
            _tag, record = rig.answer()
            tags = record["tags"]
            assert isinstance(tags, list) and tags
            distance = tags[0].get("distance_m")
            if distance is not None:
                break
        assert distance == pytest.approx(1.0, rel=0.03)


def test_status_queryable_and_liveliness_token(rig: Rig) -> None:
    rig.put_raw(SCENE)
    rig.answer()
    replies = list(rig.camera.get("perception/status", timeout=5.0))
    assert replies and replies[0].ok is not None
    import json

    status = json.loads(replies[0].ok.payload.to_string())
    assert status["frames"]["processed"] >= 1
    assert status["settings"]["dictionary"] == "DICT_4X4_50"
    tokens: queue.Queue[str] = queue.Queue()
    for reply in rig.camera.liveliness().get("perception/alive/**", timeout=5.0):
        if reply.ok is not None:
            tokens.put(str(reply.ok.key_expr))
    assert tokens.get(timeout=1).startswith("perception/alive/")


def test_run_moves_what_start_up_made_out_of_the_collectors_way(endpoint: str) -> None:
    """A full garbage collection that scans the start-up objects stalls a frame: ``run`` freezes
    them once the service is up."""
    gc.unfreeze()
    stop = threading.Event()
    exit_codes: list[int] = []
    conf = loopback_config(listen=[endpoint])
    settings = Settings(stats_interval_s=0)
    thread = threading.Thread(target=lambda: exit_codes.append(run(conf, settings, stop)))
    thread.start()
    try:
        with open_session(connect=[endpoint]) as client:
            wait_for_status(client)
            wait_until(lambda: gc.get_freeze_count() > 0, what="start-up objects frozen")
    finally:
        stop.set()
        thread.join(timeout=20)
        gc.unfreeze()
    assert exit_codes == [0]
