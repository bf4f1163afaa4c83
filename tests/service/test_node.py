"""The service in process: real Zenoh peers on loopback, real CDR, real detection."""

from __future__ import annotations

import gc
import json
import logging
import queue
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import pytest
import zenoh

from tests.helpers import (
    STREAMS,
    Collector,
    loopback_config,
    open_session,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tools.rig import marker_frame
from zenoh_perception.detect import coarse
from zenoh_perception.detect.opencv import OpenCvDetector, read_markers
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.errors import SettingsError
from zenoh_perception.pipeline import VETO_REASONS, Pending
from zenoh_perception.service.node import PerceptionService, run
from zenoh_perception.settings import Settings
from zenoh_perception.tags.selection import TagMessage
from zenoh_perception.wire.frames import RawFrameMeta, encode_image_cdr
from zenoh_perception.wire.messages import CAMERA_INFO_TYPE, TYPESTORE
from zenoh_perception.wire.records import TagCodec, decode_record, f32
from zenoh_perception_bench.scene import render_markers
from zenoh_perception_bench.scene.lookalikes import lookalike_frame

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
            tags = Collector(camera, settings.outputs.tag_key)
            records = Collector(camera, settings.outputs.record_key)
            # BLOCK: Zenoh never drops a large frame when the machine is busy
            (input_key,) = settings.inputs.input_entries
            publisher = camera.declare_publisher(
                input_key, congestion_control=zenoh.CongestionControl.BLOCK
            )
            wait_for_subscriber(publisher)
            yield Rig(service, camera, publisher, tags, records)
        finally:
            service.close()


#: The rig as a context manager, for tests with settings of their own.
rig_with = contextmanager(_rig)


@pytest.fixture
def rig(endpoint: str) -> Iterator[Rig]:
    yield from _rig(Settings.from_flat(stats_interval_s=0), endpoint)


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
    # a frame is counted once its record is out: wait for the last one, do not race it
    wait_until(
        lambda: rig.service.status()["frames"]["processed"] == len(GARBAGE),
        what="every good frame counted",
    )
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
    settings = Settings.from_flat(
        policy="center",
        tag_key="rover/tag",
        record_key="rover/tags",
        input_key="rover/image",
        stats_interval_s=0,
    )
    # Tag 3 sits on the image centre, the bigger tag 7 off to the side.
    image = render_markers(WIDTH, HEIGHT, [(3, square(300, 220, 40)), (7, square(20, 20, 150))])
    with rig_with(settings, endpoint) as rig:
        rig.put_raw(image)
        tag, _record = rig.answer()
        assert tag.tag_id == 3


def _camera_info(fx: float, fy: float | None = None) -> bytes:
    """sensor_msgs/CameraInfo CDR of a WIDTH x HEIGHT camera with focal lengths fx, fy."""
    fy = fx if fy is None else fy
    types = TYPESTORE.types
    info = types[CAMERA_INFO_TYPE](
        header=types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="zed"
        ),
        height=HEIGHT,
        width=WIDTH,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array([fx, 0, 319.5, 0, fy, 239.5, 0, 0, 1], dtype=np.float64),
        r=np.eye(3).reshape(-1),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )
    return bytes(TYPESTORE.serialize_cdr(info, CAMERA_INFO_TYPE))


def test_camera_info_enables_distance_in_the_record(endpoint: str) -> None:
    settings = Settings.from_flat(
        camera_info_key="zed/left/camera_info", tag_size_m=0.2, stats_interval_s=0
    )
    with rig_with(settings, endpoint) as rig:
        info_pub = rig.camera.declare_publisher("zed/left/camera_info")
        wait_for_subscriber(info_pub)
        info_pub.put(_camera_info(500.0))
        # CameraInfo and frames travel independently: the next frame after the intrinsics
        # are known has a distance
        wait_until(
            lambda: rig.service.status()["camera_info"]["intrinsics"] is not None,
            what="the intrinsics of the CameraInfo",
        )
        # A 100 px tag of 0.2 m seen fronto-parallel by fx=500 is 1.0 m away.
        rig.put_raw(render_markers(WIDTH, HEIGHT, [(5, square(269.5, 189.5, 100))]))
        _tag, record = rig.answer()
        tags = record["tags"]
        assert isinstance(tags, list) and len(tags) == 1
        assert tags[0]["distance_m"] == pytest.approx(1.0, rel=0.03)
        assert tags[0]["metric"] == "area"  # the distance is reported, the metric unchanged


def test_status_queryable_and_liveliness_token(rig: Rig) -> None:
    rig.put_raw(SCENE)
    rig.answer()
    wait_until(lambda: rig.service.status()["frames"]["processed"] == 1, what="the frame counted")
    replies = list(rig.camera.get("perception/status", timeout=5.0))
    assert len(replies) == 1 and replies[0].ok is not None
    assert str(replies[0].ok.encoding) == "application/json"
    status = json.loads(replies[0].ok.payload.to_string())
    assert status["frames"]["processed"] == 1
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
    settings = Settings.from_flat(stats_interval_s=0)
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


def test_distance_metric_ranks_tags_without_a_pose_after_tags_with_one(endpoint: str) -> None:
    """Tag 7 has a size (a pose, 1.67 m: closeness 0.83 over 2 m); tag 3 has none and keeps its
    area closeness (0.64), which is not comparable: tag 7 is selected."""
    settings = Settings.from_flat(
        metric="distance",
        max_range_m=2.0,
        tag_sizes=((7, 0.2),),
        camera_fx=500.0,
        camera_fy=500.0,
        camera_cx=319.5,
        camera_cy=239.5,
        stats_interval_s=0,
    )
    image = render_markers(WIDTH, HEIGHT, [(7, square(450, 60, 60)), (3, square(60, 200, 200))])
    with rig_with(settings, endpoint) as rig:
        rig.put_raw(image)
        tag, record = rig.answer()
        tags = {t["tag_id"]: t for t in record["tags"]}  # type: ignore[attr-defined]
        assert tags[3]["closeness_metric"] < tags[7]["closeness_metric"]
        assert tag.tag_id == 7
        assert tag.closeness_metric == pytest.approx(tags[7]["distance_m"] / 2.0, abs=1e-6)
        assert tags[7]["metric"] == "distance" and "distance_m" in tags[7]
        assert tags[3]["metric"] == "area" and "distance_m" not in tags[3]


def test_implausible_camera_info_is_counted_and_ignored(endpoint: str) -> None:
    settings = Settings.from_flat(
        camera_info_key="zed/left/camera_info", tag_size_m=0.2, stats_interval_s=0
    )
    with rig_with(settings, endpoint) as rig:
        info_pub = rig.camera.declare_publisher("zed/left/camera_info")
        wait_for_subscriber(info_pub)

        def camera_info() -> dict[str, Any]:
            info: dict[str, Any] = rig.service.status()["camera_info"]
            return info

        info_pub.put(_camera_info(5e7))  # no lens has that focal length in pixels
        info_pub.put(_camera_info(500.0, 50.0))  # pixels ten times taller than wide
        info_pub.put(b"\x00\x01\x00\x00garbage")
        wait_until(lambda: camera_info()["received"] == 3, what="three CameraInfo samples")
        assert camera_info() == {
            "received": 3,
            "rejected_by_reason": {"bad_intrinsics": 2, "bad_camera_info": 1},
            "size_mismatch_frames": 0,
            "intrinsics": None,
        }
        rig.put_raw(SCENE)
        _tag, record = rig.answer()
        assert all("distance_m" not in t for t in record["tags"])  # type: ignore[attr-defined]
        info_pub.put(_camera_info(500.0))
        wait_until(lambda: camera_info()["intrinsics"] is not None, what="good intrinsics")
        assert camera_info()["intrinsics"] == {"fx": 500.0, "fy": 500.0, "cx": 319.5, "cy": 239.5}
        # CameraInfo samples are no frames: the frame counters know nothing of them.
        assert rig.service.status()["frames"]["rejected"] == 0


def test_camera_info_changes_are_logged_at_most_once_per_interval(
    endpoint: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="zenoh_perception")
    settings = Settings.from_flat(
        camera_info_key="zed/left/camera_info",
        tag_size_m=0.2,
        stats_interval_s=0,
        log_interval_s=60,
    )
    with rig_with(settings, endpoint) as rig:
        info_pub = rig.camera.declare_publisher("zed/left/camera_info")
        wait_for_subscriber(info_pub)
        focals = [500.0 + 10.0 * (i % 2) for i in range(10)]  # alternating: ten changes
        for fx in focals:
            info_pub.put(_camera_info(fx))
        wait_until(
            lambda: rig.service.status()["camera_info"]["received"] == len(focals),
            what="every CameraInfo sample",
        )
        assert rig.service.status()["camera_info"]["intrinsics"]["fx"] == focals[-1]
    lines = [r.getMessage() for r in caplog.records if "event=intrinsics" in r.getMessage()]
    assert len(lines) == 1, lines


class _RefusingPublisher:
    """Stands in for a Zenoh publisher whose every put fails."""

    key = "tag"

    def put(self, *_args: object, **_kwargs: object) -> None:
        msg = "simulated put failure"
        raise zenoh.ZError(msg)


def test_a_failed_publication_is_counted_and_the_worker_goes_on(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    stream = rig.service._streams.serve("")
    assert stream is not None
    monkeypatch.setattr(stream._outputs, "_tag", _RefusingPublisher())
    rig.put_raw(SCENE, seq=1)
    record = decode_record(rig.records.get(timeout=20).payload)
    assert record["seq"] == 1 and record["selected"]["tag_id"] == 7
    wait_until(
        lambda: rig.service.status()["publish_errors"]["tag"] == 1, what="the failed put counted"
    )
    monkeypatch.undo()
    rig.put_raw(SCENE, seq=2)
    tag, record = rig.answer()
    assert tag.tag_id == 7 and record["seq"] == 2
    # the frame is counted once its publications are out: wait for it, do not race it
    wait_until(lambda: rig.service.status()["frames"]["processed"] == 2, what="both frames counted")
    status = rig.service.status()
    assert status["worker_alive"] is True
    assert status["publish_errors"] == {
        "tag": 1,
        "record": 0,
        "debug_image": 0,
        "detections": 0,
        "tf": 0,
    }


def test_negative_stamps_are_refused_alike_raw_and_cdr(rig: Rig) -> None:
    rig.put_raw(SCENE, stamp_ns=-1)
    wait_until(lambda: rig.service.status()["rejected_by_reason"] == {"bad_stamp": 1}, what="raw")
    rig.put_cdr(SCENE, stamp_ns=-1)
    wait_until(lambda: rig.service.status()["rejected_by_reason"] == {"bad_stamp": 2}, what="cdr")
    rig.put_cdr(SCENE, stamp_ns=0)
    _tag, record = rig.answer()
    assert record["stamp_ns"] == 0 and record["source"] == "cdr"


def test_vetoed_look_alikes_are_counted_by_reason(rig: Rig) -> None:
    image = lookalike_frame("keys", "DICT_4X4_50", np.random.default_rng(7))
    grey = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    expected = len(OpenCvDetector("DICT_4X4_50").detect(np.asarray(grey, np.uint8)))
    assert expected > 0  # OpenCV reads ids on these key-caps
    rig.put_raw(image)
    message, _ = rig.answer()
    assert message.tag_id == -1
    wait_until(
        lambda: sum(rig.service.status()["vetoed_by_reason"].values()) == expected,
        what="the vetoes counted",
    )
    assert set(rig.service.status()["vetoed_by_reason"]) == set(VETO_REASONS)


def test_the_tag_is_out_before_the_other_detections_are_judged(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A failure judging tag 3 (after the selected tag 7 was published) is counted as a
    # processing error: the tag stays out, the frame is not rejected, the worker goes on.
    check = Verifier.check

    def failing_on_3(self: Verifier, gray: np.ndarray, detection: Detection) -> str | None:
        if detection.tag_id == 3:
            msg = "simulated failure"
            raise ValueError(msg)
        return check(self, gray, detection)

    monkeypatch.setattr(Verifier, "check", failing_on_3)
    rig.put_raw(SCENE, seq=1)
    assert TagCodec().decode(rig.tags.get(timeout=20).payload).tag_id == 7
    wait_until(
        lambda: rig.service.status()["processing_errors"].get("detect") == 1,
        what="the failure counted",
    )
    status = rig.service.status()
    assert status["rejected_by_reason"] == {} and status["worker_alive"] is True
    monkeypatch.undo()
    rig.put_raw(SCENE, seq=2)
    tag, record = rig.answer()
    assert tag.tag_id == 7 and record["seq"] == 2  # no record was put for the first frame


def _matching(publisher: zenoh.Publisher) -> bool:
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


def test_hold_and_release_subscribe_one_camera_key_at_run_time(endpoint: str) -> None:
    with (
        open_session(listen=[endpoint]) as service_session,
        open_session(connect=[endpoint]) as camera,
        PerceptionService(service_session, STREAMS, subscribe_inputs=False) as service,
    ):
        tags = Collector(camera, "cams/*/tag")
        block = zenoh.CongestionControl.BLOCK
        front = camera.declare_publisher("cams/front/image", congestion_control=block)
        rear = camera.declare_publisher("cams/rear/image", congestion_control=block)
        frame = marker_frame(WIDTH, HEIGHT, 5, side=120)
        attachment = RawFrameMeta(WIDTH, HEIGHT, "bgra8", seq=1).to_msgpack()
        service.hold("cams/front/image")
        service.hold("cams/front/image")  # idempotent
        assert service.held() == ["cams/front/image"]
        wait_for_subscriber(front)
        assert not _matching(rear)  # not held: its frames do not even reach the service
        front.put(frame.payload, attachment=attachment)
        answer = tags.get(timeout=20)
        assert answer.key == "cams/front/tag" and TagCodec().decode(answer.payload).tag_id == 5
        assert service.streams() == ["cams/front/image"]
        service.release("cams/front/image")
        wait_until(lambda: not _matching(front), what="the subscription gone")
        assert service.held() == [] and service.streams() == []
        # the totals keep the count (the worker counts the frame once its tag is out)
        wait_until(lambda: service.status()["frames"]["processed"] == 1, what="the frame counted")
        with pytest.raises(SettingsError, match="cams/\\*/image"):
            service.hold("cams/*/image")
        with pytest.raises(SettingsError, match="input_key"):
            service.hold("elsewhere/image")


def test_a_list_of_cameras_each_takes_the_camera_info_of_its_own_entry(endpoint: str) -> None:
    """input_key and camera_info_key both lists: a CameraInfo goes to the stream named as
    its key is under camera_info_key's list (rear's to rear only)."""
    settings = STREAMS.with_flat(
        input_key=("cams/front/image", "cams/rear/image"),
        camera_info_key=("cams/front/camera_info", "cams/rear/camera_info"),
        tag_size_m=0.2,
    )
    with (
        open_session(listen=[endpoint]) as service_session,
        open_session(connect=[endpoint]) as camera,
        PerceptionService(service_session, settings) as service,
    ):
        records = Collector(camera, "cams/*/perception/tags")
        info = camera.declare_publisher("cams/rear/camera_info")
        wait_for_subscriber(info)
        info.put(_camera_info(500.0))
        wait_until(lambda: service.status()["camera_info"]["received"] == 1, what="the CameraInfo")
        image = render_markers(WIDTH, HEIGHT, [(5, square(269.5, 189.5, 100))])
        distances: dict[str, object] = {}
        for name in ("front", "rear"):
            publisher = camera.declare_publisher(f"cams/{name}/image")
            wait_for_subscriber(publisher)
            attachment = RawFrameMeta(WIDTH, HEIGHT).to_msgpack()
            publisher.put(image.tobytes(), attachment=attachment)
            sample = records.get(timeout=20)
            assert sample.key == f"cams/{name}/perception/tags"
            (tag,) = decode_record(sample.payload)["tags"]
            distances[name] = tag.get("distance_m")
        assert distances["front"] is None
        assert distances["rear"] == pytest.approx(1.0, rel=0.03)
        named = {s["name"]: s["camera_info"]["intrinsics"] for s in service.status()["streams"]}
        assert named["front"] is None and named["rear"]["fx"] == 500.0


#: The coarse first read on, under a deadline short enough for a test.
def test_a_frame_whose_analysis_fails_after_its_tag_is_processed_without_a_record(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the tag is out before the rest of the frame is judged: a failure there loses the record
    # only, counted as a processing error; the frame was answered, so it is processed
    def failing(self: Pending) -> Any:
        msg = "simulated failure after the tag"
        raise cv2.error(msg)

    monkeypatch.setattr(Pending, "finish", failing)
    with rig_with(Settings.from_flat(stats_interval_s=0), endpoint) as rig:
        rig.put_raw(SCENE, seq=1)
        assert TagCodec().decode(rig.tags.get(timeout=20).payload).tag_id == 7
        wait_until(
            lambda: rig.service.status()["processing_errors"] == {"detect": 1},
            what="the failure counted",
        )
        status = rig.service.status()
        assert status["frames"] == {"received": 1, "processed": 1, "dropped": 0, "rejected": 0}
        assert status["worker_alive"] is True


COARSE = Settings.from_flat(stats_interval_s=0, coarse_first_read=True, frame_deadline_ms=300)


def _coarse_stream(rig: Rig) -> dict[str, Any]:
    """The one stream's status, its first frame (SCENE, tag 7 at 160 px) answered: the next
    frame is read coarsely first."""
    rig.put_raw(SCENE, seq=1)
    tag, record = rig.answer()
    assert tag.tag_id == 7 and record["seq"] == 1
    wait_until(lambda: rig.service.status()["frames"]["processed"] == 1, what="frame 1 counted")
    streams: list[dict[str, Any]] = rig.service.status()["streams"]
    assert len(streams) == 1
    return streams[0]


def test_a_coarse_read_past_the_frame_deadline_is_abandoned_like_any_read(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a periodic pattern just above the coarse read's smallest marker can take OpenCV most of
    # a second: the frame deadline abandons that read as it does the detector's
    release = threading.Event()
    calls: list[tuple[int, ...]] = []

    def stalling_once(*args: Any) -> Any:
        calls.append(args[1].shape)
        if len(calls) == 1:  # the first coarse read, frame 2's half-size one
            release.wait(60.0)
        return read_markers(*args)

    monkeypatch.setattr(coarse, "read_markers", stalling_once)
    with rig_with(COARSE, endpoint) as rig:
        try:
            stream = _coarse_stream(rig)
            assert stream["coarse_read"] == {"reads": 0, "answered": 0, "slow": 0}
            rig.put_raw(SCENE, seq=2)
            wait_until(
                lambda: rig.service.status()["budget"]["abandoned"] == 1,
                timeout=20.0,
                what="the coarse read abandoned at the deadline",
            )
            assert calls == [(HEIGHT // 2, WIDTH // 2)]
            # the frame is rejected as any frame past the deadline, and the next answered
            rig.put_raw(SCENE, seq=3)
            tag, record = rig.answer()
            assert tag.tag_id == 7 and record["seq"] == 3
            wait_until(
                lambda: rig.service.status()["frames"]["processed"] == 2, what="frame 3 counted"
            )
            status = rig.service.status()
            assert status["rejected_by_reason"] == {"abandoned": 1}
            assert status["frames"] == {"received": 3, "processed": 2, "dropped": 0, "rejected": 1}
            # the abandoned read counts as slow: the stream's next frames are read whole
            (stream,) = status["streams"]
            assert stream["coarse_read"] == {"reads": 1, "answered": 0, "slow": 1}
        finally:
            release.set()


def test_a_whole_read_abandoned_after_the_coarse_read_s_tag_is_no_rejection(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the frame's tag is out: the read for its record, abandoned, loses the record only
    stall, release = threading.Event(), threading.Event()
    detect = OpenCvDetector.detect

    def stalling(self: OpenCvDetector, gray: np.ndarray, *args: Any, **kwargs: Any) -> Any:
        if stall.is_set():
            release.wait(60.0)
        return detect(self, gray, *args, **kwargs)

    monkeypatch.setattr(OpenCvDetector, "detect", stalling)
    with rig_with(COARSE, endpoint) as rig:
        try:
            _coarse_stream(rig)
            stall.set()
            rig.put_raw(SCENE, seq=2)
            assert TagCodec().decode(rig.tags.get(timeout=20).payload).tag_id == 7
            wait_until(
                lambda: rig.service.status()["processing_errors"].get("whole_read") == 1,
                timeout=20.0,
                what="the whole read abandoned",
            )
            status = rig.service.status()
            assert status["rejected_by_reason"] == {}
            assert status["budget"]["abandoned"] == 1
            # answered, so processed: received = processed + dropped + rejected holds
            frames = status["frames"]
            assert frames["processed"] == frames["received"] >= 2
            (stream,) = status["streams"]
            assert stream["coarse_read"] == {"reads": 1, "answered": 1, "slow": 0}
            assert stream["processing_errors"] == {"whole_read": 1}
        finally:
            release.set()
