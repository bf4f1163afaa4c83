"""The perception/tags record, its JSON Schemas, the mailbox and the counters."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import jsonschema
import msgpack
import pytest

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.service.mailbox import LatestMailbox
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.tags.selection import NO_TAG, Metric, TagObservation
from zenoh_perception.wire.frames import RawFrameMeta, decode_attachment
from zenoh_perception.wire.records import FrameRecord, TagCodec, decode_record, f32

SCHEMAS = Path(__file__).resolve().parent.parent / "schemas"


def _schema(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((SCHEMAS / name).read_text())
    jsonschema.Draft202012Validator.check_schema(data)
    return data


def _record(tags: tuple[TagObservation, ...]) -> FrameRecord:
    selected = tags[0].message() if tags else NO_TAG
    return FrameRecord(
        stamp_ns=1_700_000_000_000_000_000,
        frame_id="zed_left",
        seq=12,
        width=1280,
        height=720,
        selected=selected,
        tags=tags,
        timing_ms={"latency_ms": 3.25, "detect_ms": 2.0},
        source="raw",
    )


TAG = TagObservation(
    7,
    100.1,
    200.2,
    0.8123456789,
    ((90.0, 190.0), (110.0, 190.0), (110.0, 210.0), (90.0, 210.0)),
    400.0,
    distance_m=2.5,
    rvec=(0.1, 0.2, 0.3),
    tvec=(0.0, 0.5, 2.4),
    metric=Metric.DISTANCE,
)
#: A tag without a pose: its closeness comes from its area.
AREA_TAG = TagObservation(
    9, 300.0, 100.0, 0.7, ((290.0, 90.0), (310.0, 90.0), (310.0, 110.0), (290.0, 110.0)), 400.0
)


@pytest.mark.parametrize("tags", [(), (TAG,)])
def test_record_roundtrip_matches_the_schema(tags: tuple[TagObservation, ...]) -> None:
    record = decode_record(_record(tags).to_msgpack())
    jsonschema.validate(record, _schema("perception-tags.schema.json"))
    assert record["seq"] == 12 and record["width"] == 1280 and record["source"] == "raw"
    assert len(record["tags"]) == len(tags)
    if tags:
        assert record["tags"][0]["corners"][2] == [110.0, 210.0]
        assert record["tags"][0]["distance_m"] == 2.5
    else:
        assert record["selected"]["tag_id"] == -1


def test_each_tag_of_the_record_says_which_metric_its_closeness_used() -> None:
    schema = _schema("perception-tags.schema.json")
    record = decode_record(_record((TAG, AREA_TAG)).to_msgpack())
    jsonschema.validate(record, schema)
    assert [tag["metric"] for tag in record["tags"]] == ["distance", "area"]
    assert "distance_m" not in record["tags"][1]
    for tag in record["tags"]:
        del tag["metric"]
    with pytest.raises(jsonschema.ValidationError, match="metric"):
        jsonschema.validate(record, schema)
    record["tags"][0]["metric"] = "loudness"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(record, schema)


def test_record_selected_equals_the_tag_message_bit_for_bit() -> None:
    codec = TagCodec()
    record = decode_record(_record((TAG,)).to_msgpack())
    tag = codec.decode(bytes(codec.encode(TAG.message())))
    assert record["selected"]["closeness_metric"] == tag.closeness_metric == f32(0.8123456789)
    assert record["selected"]["x_tag_center_pixel"] == tag.x_tag_center_pixel


def test_schema_rejects_a_record_without_selection() -> None:
    record = decode_record(_record(()).to_msgpack())
    del record["selected"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(record, _schema("perception-tags.schema.json"))


@pytest.mark.parametrize("payload", [b"", b"\xc1", msgpack.packb([1]), msgpack.packb({"seq": 1})])
def test_decode_record_rejects_garbage(payload: bytes) -> None:
    with pytest.raises(MessageDecodeError):
        decode_record(payload)


def test_attachment_schema_agrees_with_the_decoder() -> None:
    schema = _schema("frame-attachment.schema.json")
    meta = RawFrameMeta(640, 480, "bgr8", step=1920, stamp_ns=5, frame_id="cam", seq=3)
    jsonschema.validate(msgpack.unpackb(meta.to_msgpack()), schema)
    assert decode_attachment(meta.to_msgpack()) == meta
    assert set(schema["properties"]["encoding"]["enum"]) == {
        "bgra8",
        "bgr8",
        "rgba8",
        "rgb8",
        "mono8",
    }


# -- mailbox --------------------------------------------------------------------------------


def test_mailbox_keeps_only_the_newest_and_counts_drops() -> None:
    box: LatestMailbox[int] = LatestMailbox()
    assert box.put(1) is False
    assert box.put(2) is True
    assert box.put(3) is True
    assert box.take(0.0) == 3
    assert box.take(0.0) is None
    assert box.dropped == 2


def test_mailbox_wakes_a_waiting_consumer_and_close_releases_it() -> None:
    box: LatestMailbox[str] = LatestMailbox()
    got: list[str | None] = []
    consumer = threading.Thread(target=lambda: got.append(box.take(10.0)))
    consumer.start()
    box.put("frame")
    consumer.join(10.0)
    assert got == ["frame"]
    closer = threading.Thread(target=lambda: got.append(box.take(10.0)))
    closer.start()
    box.close()
    closer.join(10.0)
    assert got == ["frame", None] and not closer.is_alive()
    assert box.put("late") is False and box.take(0.0) is None


# -- stats ----------------------------------------------------------------------------------


def test_stats_percentiles_and_counts() -> None:
    now = [100.0]
    stats = ServiceStats(clock=lambda: now[0])
    for i in range(100):
        stats.on_received(dropped_one=i % 10 == 0)
        now[0] += 0.1
        stats.on_processed(float(i + 1))
    stats.on_rejected("bad_cdr")
    stats.on_rejected("bad_cdr")
    now[0] += 0.05  # off the 0.1 s grid: no frame sits on the edge of the 5 s fps window
    snap = stats.snapshot()
    assert (snap.received, snap.processed, snap.dropped) == (100, 100, 10)
    assert snap.rejected == {"bad_cdr": 2}
    assert snap.latency_p50_ms == pytest.approx(50.5)
    assert snap.latency_p99_ms == pytest.approx(99.01)
    assert snap.fps == pytest.approx(10.0)
    assert snap.as_dict()["frames"]["rejected"] == 2


def test_fps_is_frames_over_wall_time() -> None:
    """Two frames done 1 ms apart, then a quiet second: 2 frames in 2 s of uptime, not 1000
    frames per second."""
    now = [0.0]
    stats = ServiceStats(clock=lambda: now[0])
    now[0] = 1.0
    stats.on_processed(1.0)
    now[0] = 1.001
    stats.on_processed(1.0)
    now[0] = 2.0
    assert stats.snapshot().fps == pytest.approx(1.0)
    now[0] = 10.0  # the window (5 s) is full and holds both frames no more
    assert stats.snapshot().fps == 0.0
    for _ in range(50):  # 10 Hz for 5 s
        now[0] += 0.1
        stats.on_processed(1.0)
    now[0] += 0.05
    assert stats.snapshot().fps == pytest.approx(10.0)


def test_budget_counts_frames_over_it_and_keeps_the_worst_times() -> None:
    stats = ServiceStats(frame_budget_ms=10.0)
    stats.on_processed(5.0, frame_ms=9.0, detect_ms=7.0)
    stats.on_processed(25.0, frame_ms=24.5, detect_ms=20.0)
    stats.on_processed(12.0, frame_ms=11.0, detect_ms=21.0)
    budget = stats.snapshot().as_dict()["budget"]
    assert budget == {
        "frame_budget_ms": 10.0,
        "over_budget": 2,
        "frame_ms_max": 24.5,
        "detect_ms_max": 21.0,
    }


def test_publish_processing_and_camera_info_counters() -> None:
    stats = ServiceStats()
    stats.on_publish_error("record")
    stats.on_processing_error("debug_image")
    stats.on_camera_info("bad_intrinsics")
    stats.on_camera_info(None)
    status = stats.snapshot().as_dict()
    assert status["publish_errors"] == {"tag": 0, "record": 1, "debug_image": 0}
    assert status["processing_errors"] == {"debug_image": 1}
    assert status["camera_info"] == {"received": 2, "rejected_by_reason": {"bad_intrinsics": 1}}
    # Neither is a frame: the frame counters stay as they were.
    assert status["frames"] == {"received": 0, "processed": 0, "dropped": 0, "rejected": 0}


def test_log_gate_admits_once_per_interval_and_reports_suppressed() -> None:
    now = [0.0]
    gate = LogGate(5.0, clock=lambda: now[0])
    assert gate.admit("bad_cdr") == 0
    assert gate.admit("bad_cdr") is None
    assert gate.admit("bad_cdr") is None
    assert gate.admit("size_mismatch") == 0
    now[0] = 5.0
    assert gate.admit("bad_cdr") == 2


# -- logs -----------------------------------------------------------------------------------


def test_log_values_cannot_break_a_line_or_forge_a_key() -> None:
    import logging

    from zenoh_perception.service.logs import KeyValueFormatter, kv

    line = kv(reason="bad_cdr", detail='say "hi"\nlevel=ERROR', empty="")
    assert line == 'reason=bad_cdr detail="say \\"hi\\"\\nlevel=ERROR" empty=""'
    record = logging.LogRecord(
        "x", logging.WARNING, __file__, 1, "event=rejected %s", (line,), None
    )
    formatted = KeyValueFormatter().format(record)
    assert "\n" not in formatted
    assert formatted.startswith("ts=") and " level=WARNING logger=x event=rejected " in formatted
