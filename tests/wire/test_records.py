"""Output encodings: the tag CDR message (byte-identical to rosbags' StarterProjectTag: golden
bytes commented field by field, and a property over the whole int32 / float32 ranges) and the
perception/tags record with its JSON Schema."""

from __future__ import annotations

import json
import math
import struct
from dataclasses import replace
from typing import Any

import jsonschema
import msgpack
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import REPO
from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.tags.pose import quaternion_from_rvec
from zenoh_perception.tags.selection import NO_TAG, Metric, TagMessage, TagObservation
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.messages import (
    make_typestore,
    tag_type_name,
)
from zenoh_perception.wire.records import (
    TAG_CDR_SIZE,
    FrameRecord,
    TagCodec,
    decode_record,
    f32,
    message_fields,
)
from zenoh_perception.wire.text import format_decoded_record

SCHEMAS = REPO / "schemas"


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
        source=InputKind.RAW,
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


# -- the perception/tags record --------------------------------------------------------------------


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


@pytest.mark.parametrize(
    ("kind", "text"),
    [(InputKind.RAW, "raw"), (InputKind.CDR, "cdr"), (InputKind.COMPRESSED, "compressed")],
)
def test_the_record_names_its_source_and_stream_as_plain_text(kind: InputKind, text: str) -> None:
    record = replace(_record(()), source=kind, input_key="cams/front/image")
    packed = record.to_msgpack()
    assert msgpack.packb("source") + msgpack.packb(text) in packed
    assert msgpack.packb("stream") + msgpack.packb("cams/front/image") in packed


def test_a_pose_carries_its_rotation_as_a_quaternion_too() -> None:
    schema = _schema("perception-tags.schema.json")
    record = decode_record(_record((TAG, AREA_TAG)).to_msgpack())
    jsonschema.validate(record, schema)
    pose = record["tags"][0]["pose"]
    assert pose["rvec"] == [0.1, 0.2, 0.3] and pose["tvec"] == [0.0, 0.5, 2.4]
    assert pose["quaternion"] == list(quaternion_from_rvec((0.1, 0.2, 0.3)))
    assert "pose" not in record["tags"][1]
    pose["quaternion"] = [0.0, 0.0, 1.0]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(record, schema)


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


def test_each_tag_of_the_record_names_its_dictionary_when_known() -> None:
    named = TagObservation(
        23, 50.0, 50.0, 0.9, AREA_TAG.corners, 400.0, dictionary="DICT_APRILTAG_16h5"
    )
    record = decode_record(_record((named, AREA_TAG)).to_msgpack())
    jsonschema.validate(record, _schema("perception-tags.schema.json"))
    assert record["tags"][0]["dictionary"] == "DICT_APRILTAG_16h5"
    assert "dictionary" not in record["tags"][1]


def test_record_selected_equals_the_tag_message_bit_for_bit() -> None:
    codec = TagCodec()
    record = decode_record(_record((TAG,)).to_msgpack())
    tag = codec.decode(bytes(codec.encode(TAG.message())))
    assert record["selected"]["closeness_metric"] == tag.closeness_metric == f32(0.8123456789)
    assert record["selected"]["x_tag_center_pixel"] == tag.x_tag_center_pixel


def test_the_whole_read_s_selection_is_there_only_where_the_tag_published_differs() -> None:
    schema = _schema("perception-tags.schema.json")
    plain = decode_record(_record((TAG, AREA_TAG)).to_msgpack())
    assert "whole_selected" not in plain
    differs = replace(_record((TAG, AREA_TAG)), whole_selected=AREA_TAG.message())
    record = decode_record(differs.to_msgpack())
    jsonschema.validate(record, schema)
    assert record["whole_selected"] == message_fields(AREA_TAG.message())
    assert record["selected"] == plain["selected"]  # what ``tag`` published
    del record["whole_selected"]
    assert record == plain  # every other field as it was
    broken = msgpack.packb({**record, "whole_selected": {"tag_id": "9"}})
    with pytest.raises(MessageDecodeError):
        decode_record(broken)


def test_schema_rejects_a_record_without_selection() -> None:
    record = decode_record(_record(()).to_msgpack())
    del record["selected"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(record, _schema("perception-tags.schema.json"))


@pytest.mark.parametrize("payload", [b"", b"\xc1", msgpack.packb([1]), msgpack.packb({"seq": 1})])
def test_decode_record_rejects_garbage(payload: bytes) -> None:
    with pytest.raises(MessageDecodeError):
        decode_record(payload)


# -- tag: byte-identical to rosbags' StarterProjectTag ---------------------------------------------


INT32 = st.integers(min_value=-(2**31), max_value=2**31 - 1)


FLOAT32 = st.floats(width=32, allow_nan=True, allow_infinity=True)


def _rosbags_tag_cdr(msg: TagMessage, package: str = "mrover") -> bytes:
    """The tag as rosbags serialises it, from a typestore built here (not the codec's)."""
    store = make_typestore(package)
    name = tag_type_name(package)
    instance = store.types[name](
        tag_id=msg.tag_id,
        x_tag_center_pixel=msg.x_tag_center_pixel,
        y_tag_center_pixel=msg.y_tag_center_pixel,
        closeness_metric=msg.closeness_metric,
    )
    return bytes(store.serialize_cdr(instance, name, little_endian=True))


def _f32_bits(value: float) -> bytes:
    return struct.pack("<f", value)


def _same_message(a: TagMessage, b: TagMessage) -> bool:
    """Equal field by field, NaN equal to NaN with the same bits."""
    return a.tag_id == b.tag_id and all(
        _f32_bits(x) == _f32_bits(y)
        for x, y in [
            (a.x_tag_center_pixel, b.x_tag_center_pixel),
            (a.y_tag_center_pixel, b.y_tag_center_pixel),
            (a.closeness_metric, b.closeness_metric),
        ]
    )


# Every sample: 4-byte encapsulation header (00 01 = CDR little-endian, 00 00 = options), then
# int32 tag_id, float32 x_tag_center_pixel, float32 y_tag_center_pixel, float32
# closeness_metric, all little-endian, naturally aligned (no padding: 4-byte fields after a
# 4-byte header).
GOLDEN: list[tuple[TagMessage, str]] = [
    (
        TagMessage(7, 640.5, 360.25, 0.125),
        "00 01 00 00"  # header: CDR_LE, options 0
        " 07 00 00 00"  # tag_id 7
        " 00 20 20 44"  # x 640.5 = 0x44202000
        " 00 20 b4 43"  # y 360.25 = 0x43b42000
        " 00 00 00 3e",  # closeness 0.125 = 0x3e000000
    ),
    (
        NO_TAG,  # the dummy published when no tag is seen
        "00 01 00 00"  # header
        " ff ff ff ff"  # tag_id -1 (two's complement)
        " 00 00 00 00"  # x 0.0
        " 00 00 00 00"  # y 0.0
        " 00 00 00 00",  # closeness 0.0
    ),
    (
        TagMessage(-(2**31), -12.75, -0.0, 3.4028234663852886e38),
        "00 01 00 00"  # header
        " 00 00 00 80"  # tag_id INT32_MIN
        " 00 00 4c c1"  # x -12.75 = 0xc14c0000 (sign bit set)
        " 00 00 00 80"  # y -0.0: only the sign bit
        " ff ff 7f 7f",  # closeness FLT_MAX = 0x7f7fffff
    ),
    (
        TagMessage(2**31 - 1, math.nan, math.inf, -math.inf),
        "00 01 00 00"  # header
        " ff ff ff 7f"  # tag_id INT32_MAX
        " 00 00 c0 7f"  # x NaN (quiet NaN 0x7fc00000)
        " 00 00 80 7f"  # y +inf = 0x7f800000
        " 00 00 80 ff",  # closeness -inf = 0xff800000
    ),
    (
        TagMessage(49, 0.1, 1e-45, 1.0),
        "00 01 00 00"  # header
        " 31 00 00 00"  # tag_id 49 (last id of DICT_4X4_50)
        " cd cc cc 3d"  # x 0.1 rounded to the nearest float32 0x3dcccccd
        " 01 00 00 00"  # y 1e-45 -> smallest subnormal float32 0x00000001
        " 00 00 80 3f",  # closeness 1.0 = 0x3f800000
    ),
]


@pytest.mark.parametrize(("msg", "golden_hex"), GOLDEN)
def test_tag_matches_golden_bytes_and_rosbags(msg: TagMessage, golden_hex: str) -> None:
    golden = bytes.fromhex(golden_hex)
    assert len(golden) == TAG_CDR_SIZE
    assert _rosbags_tag_cdr(msg) == golden
    assert bytes(TagCodec().encode(msg)) == golden
    decoded = TagCodec().decode(golden)
    expected = TagMessage(
        msg.tag_id,
        *(struct.unpack("<f", _f32_bits(v))[0] for v in _fields(msg)),
    )
    assert _same_message(decoded, expected)


def _fields(msg: TagMessage) -> tuple[float, float, float]:
    return (msg.x_tag_center_pixel, msg.y_tag_center_pixel, msg.closeness_metric)


@given(tag_id=INT32, x=FLOAT32, y=FLOAT32, closeness=FLOAT32)
def test_tag_is_rosbags_serialisation_for_all_ids_and_floats(
    tag_id: int, x: float, y: float, closeness: float
) -> None:
    msg = TagMessage(tag_id, x, y, closeness)
    encoded = bytes(TagCodec().encode(msg))
    assert encoded == _rosbags_tag_cdr(msg)
    # An independent oracle of the layout: header, then "<i f f f".
    assert encoded == b"\x00\x01\x00\x00" + struct.pack("<i3f", tag_id, x, y, closeness)
    assert _same_message(TagCodec().decode(encoded), msg)


@given(tag_id=INT32, x=st.floats(-3e38, 3e38), y=st.floats(-3e38, 3e38), closeness=st.floats())
def test_tag_rounds_python_floats_to_float32_as_rosbags_does(
    tag_id: int, x: float, y: float, closeness: float
) -> None:
    msg = TagMessage(tag_id, x, y, closeness)
    try:
        expected = _rosbags_tag_cdr(msg)
    except OverflowError:
        with pytest.raises(OverflowError):
            TagCodec().encode(msg)
        return
    assert bytes(TagCodec().encode(msg)) == expected


@given(tag_id=INT32, x=FLOAT32, y=FLOAT32, closeness=FLOAT32)
def test_ros_package_changes_the_type_name_not_the_bytes(
    tag_id: int, x: float, y: float, closeness: float
) -> None:
    msg = TagMessage(tag_id, x, y, closeness)
    default, custom = TagCodec(), TagCodec("my_robot_msgs")
    assert (default.type_name, custom.type_name) == (
        "mrover/msg/StarterProjectTag",
        "my_robot_msgs/msg/StarterProjectTag",
    )
    encoded = bytes(custom.encode(msg))
    assert encoded == bytes(default.encode(msg)) == _rosbags_tag_cdr(msg, "my_robot_msgs")
    assert _same_message(default.decode(encoded), msg)


def test_tag_from_a_big_endian_ros_publisher_decodes() -> None:
    # CDR_BE (00 00) is legal on the wire; a big-endian ROS 2 node would send it.
    msg = TagMessage(12, 100.5, -3.25, 0.75)
    store = make_typestore()
    name = tag_type_name()
    instance = store.types[name](
        tag_id=12, x_tag_center_pixel=100.5, y_tag_center_pixel=-3.25, closeness_metric=0.75
    )
    big = bytes(store.serialize_cdr(instance, name, little_endian=False))
    assert big == bytes.fromhex("00 00 00 00 00 00 00 0c 42 c9 00 00 c0 50 00 00 3f 40 00 00")
    assert _same_message(TagCodec().decode(big), msg)


# -- properties ------------------------------------------------------------------------------------


_FINITE = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)
_OBSERVATIONS = st.builds(
    TagObservation,
    tag_id=st.integers(min_value=0, max_value=999),
    x=_FINITE,
    y=_FINITE,
    closeness=st.floats(min_value=0.0, max_value=1.0),
    corners=st.tuples(*[st.tuples(_FINITE, _FINITE)] * 4),
    area_px=st.floats(min_value=0.0, max_value=1e7),
)


@given(
    tags=st.lists(_OBSERVATIONS, max_size=4),
    stamp_ns=st.integers(min_value=0, max_value=2**63 - 1),
    seq=st.integers(min_value=-(2**63), max_value=2**63 - 1),
    frame_id=st.text(max_size=16),
)
def test_any_record_decodes_to_what_was_encoded(
    tags: list[TagObservation], stamp_ns: int, seq: int, frame_id: str
) -> None:
    selected = tags[0].message() if tags else NO_TAG
    record = FrameRecord(
        stamp_ns, frame_id, seq, 640, 480, selected, tuple(tags), {"latency_ms": 1.0}, InputKind.RAW
    )
    decoded = decode_record(record.to_msgpack())
    assert (decoded["stamp_ns"], decoded["seq"], decoded["frame_id"]) == (stamp_ns, seq, frame_id)
    assert decoded["selected"] == message_fields(selected)
    assert [t["tag_id"] for t in decoded["tags"]] == [t.tag_id for t in tags]
    assert [t["corners"] for t in decoded["tags"]] == [[list(c) for c in t.corners] for t in tags]
    assert all(
        t["closeness_metric"] == f32(o.closeness)
        for t, o in zip(decoded["tags"], tags, strict=True)
    )


@given(st.binary(max_size=256))
def test_any_bytes_decode_to_a_record_or_the_decode_error(payload: bytes) -> None:
    try:
        record = decode_record(payload)
    except MessageDecodeError:
        return
    assert {"stamp_ns", "seq", "selected", "tags"} <= set(record)


@given(st.binary(max_size=64))
def test_any_bytes_decode_to_a_tag_or_the_decode_error(payload: bytes) -> None:
    try:
        tag = TagCodec().decode(payload)
    except MessageDecodeError:
        return
    assert len(payload) >= TAG_CDR_SIZE
    assert -(2**31) <= tag.tag_id < 2**31


_MSGPACK_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text()
    | st.binary(max_size=4),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=12,
)


@given(
    changes=st.dictionaries(
        st.sampled_from(["stamp_ns", "seq", "width", "frame_id", "selected", "tags", "timing"]),
        _MSGPACK_VALUES,
        max_size=3,
    )
)
def test_a_decoded_record_always_prints_as_strict_json(changes: dict[str, object]) -> None:
    tag = TagObservation(4, 50.0, 60.0, 0.5, ((45, 55), (55, 55), (55, 65), (45, 65)), 100.0)
    record = msgpack.unpackb(
        FrameRecord(
            7, "c", 7, 64, 48, tag.message(), (tag,), {"latency_ms": 1.0}, InputKind.RAW
        ).to_msgpack()
    )
    record.update(changes)
    try:
        decoded = decode_record(msgpack.packb(record))
    except MessageDecodeError:
        return
    json.dumps(decoded, allow_nan=False)
    format_decoded_record("k", decoded, as_json=False)


def test_a_pose_says_whether_it_may_be_flipped_with_both_solutions_errors() -> None:
    schema = _schema("perception-tags.schema.json")
    flippable = replace(TAG, tag_id=8, metric=Metric.AREA, ambiguous=True, pose_errors=(0.04, 0.05))
    record = decode_record(_record((TAG, flippable)).to_msgpack())
    jsonschema.validate(record, schema)
    clear, ambiguous = (tag["pose"] for tag in record["tags"])
    assert clear["ambiguous"] is False and "reprojection_px" not in clear
    assert ambiguous["ambiguous"] is True and ambiguous["reprojection_px"] == [0.04, 0.05]
    ambiguous["ambiguous"] = "maybe"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(record, schema)
