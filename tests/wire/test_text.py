"""The outputs as one line each, as ``echo`` and ``demo`` print them: JSON that holds exactly the
decoded message, or one line of text whose fields a reader can pick out."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import parse_pairs
from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.tags.selection import NO_TAG, TagMessage, TagObservation
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.records import FrameRecord, TagCodec, decode_record, f32
from zenoh_perception.wire.text import format_decoded_record, format_record, format_tag

CODEC = TagCodec()


def _record(*tags: TagObservation, seq: int = 41) -> bytes:
    return FrameRecord(
        stamp_ns=1_700_000_000_000_000_123,
        frame_id="zed_left",
        seq=seq,
        width=1280,
        height=720,
        selected=tags[0].message() if tags else NO_TAG,
        tags=tags,
        timing_ms={"latency_ms": 3.14159, "detect_ms": 2.0},
        source=InputKind.CDR,
    ).to_msgpack()


def _tag(tag_id: int, x: float, y: float) -> TagObservation:
    corners = ((x - 5, y - 5), (x + 5, y - 5), (x + 5, y + 5), (x - 5, y + 5))
    return TagObservation(tag_id, x, y, 0.75, corners, 100.0)


@given(
    tag_id=st.integers(min_value=-(2**31), max_value=2**31 - 1),
    x=st.floats(width=32, allow_nan=False, allow_infinity=False),
    y=st.floats(width=32, allow_nan=False, allow_infinity=False),
    closeness=st.floats(width=32, allow_nan=False, allow_infinity=False),
)
def test_a_tag_as_json_is_the_decoded_message(
    tag_id: int, x: float, y: float, closeness: float
) -> None:
    payload = bytes(CODEC.encode(TagMessage(tag_id, x, y, closeness)))
    assert json.loads(format_tag("rover/tag", payload, CODEC, as_json=True)) == {
        "key": "rover/tag",
        "tag_id": tag_id,
        "x_tag_center_pixel": x,
        "y_tag_center_pixel": y,
        "closeness_metric": closeness,
    }


def test_a_tag_as_text_names_each_field() -> None:
    payload = bytes(CODEC.encode(TagMessage(7, 640.5, 360.25, 0.125)))
    line = format_tag("tag", payload, CODEC, as_json=False)
    assert line.startswith("[tag] ")
    fields = parse_pairs(line)
    assert fields == {"tag_id": "7", "x": "640.50", "y": "360.25", "closeness": "0.1250"}


def test_a_record_as_json_is_the_decoded_record_under_its_key() -> None:
    payload = _record(_tag(3, 100.0, 200.0), _tag(9, 300.0, 50.0))
    printed = json.loads(format_record("perception/tags", payload, as_json=True))
    assert printed.pop("key") == "perception/tags"
    assert printed == decode_record(payload)
    assert printed["selected"]["closeness_metric"] == f32(0.75)


def test_a_record_as_text_lists_its_tags_and_selection() -> None:
    line = format_record(
        "perception/tags", _record(_tag(3, 100, 200), _tag(9, 300, 50)), as_json=False
    )
    fields = parse_pairs(line)
    assert fields == {
        "seq": "41",
        "stamp_ns": "1700000000000000123",
        "tags": "3,9",
        "selected": "3",
        "latency_ms": "3.14",
    }
    assert "1280x720" in line.split()


def test_a_record_without_tags_or_latency_as_text() -> None:
    record = decode_record(_record(seq=2))
    del record["timing"]["latency_ms"]
    fields = parse_pairs(format_decoded_record("perception/tags", record, as_json=False))
    assert (fields["tags"], fields["selected"]) == ("-", "-1")
    assert math.isnan(float(fields["latency_ms"]))


@pytest.mark.parametrize("payload", [b"", b"\x00\x01\x00\x00\x01"])
def test_undecodable_payloads_raise_the_decode_error(payload: bytes) -> None:
    with pytest.raises(MessageDecodeError):
        format_tag("tag", payload, CODEC, as_json=True)
    with pytest.raises(MessageDecodeError):
        format_record("perception/tags", payload, as_json=True)
