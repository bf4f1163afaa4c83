"""Output encodings: the ``tag`` CDR message and the ``perception/tags`` msgpack record.

``tag`` is byte for byte what a ROS 2 publisher of StarterProjectTag sends (serialised by
rosbags): ``00 01 00 00`` (CDR little-endian encapsulation), int32 tag_id, float32 x, float32 y,
float32 closeness — 20 bytes.

The record is described by ``schemas/perception-tags.schema.json``. Its message fields are
rounded to float32 so that they equal the ``tag`` message of the same frame exactly.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import msgpack
import numpy as np

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.tags.pose import quaternion_from_rvec
from zenoh_perception.tags.selection import TagMessage, TagObservation
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.messages import (
    DEFAULT_ROS_PACKAGE,
    deserialize,
    make_typestore,
    tag_type_name,
    unpack_msgpack_map,
)

TAG_CDR_SIZE: Final = 20
#: The ``tag`` message's bytes: encapsulation, int32 tag_id, float32 x, y and closeness.
_TAG_CDR: Final = struct.Struct("<4si3f")
_CDR_LITTLE_ENDIAN: Final = b"\x00\x01\x00\x00"
MESSAGE_FIELDS: Final = (
    "tag_id",
    "x_tag_center_pixel",
    "y_tag_center_pixel",
    "closeness_metric",
)


def f32(value: float) -> float:
    """``value`` rounded to the nearest float32 (as the CDR message carries it)."""
    return float(np.float32(value))


class TagCodec:
    """Serialise / deserialise StarterProjectTag CDR with rosbags."""

    def __init__(self, package: str = DEFAULT_ROS_PACKAGE) -> None:
        self._store = make_typestore(package)
        self.type_name = tag_type_name(package)

    def encode(self, msg: TagMessage) -> memoryview:
        """The message's CDR, as rosbags serialises it (the tests hold them equal), packed
        at once: it is put on every frame before anything else is done.

        Raises:
            struct.error: ``tag_id`` is not an int32.
            OverflowError: a float beyond float32's range.

        """
        return memoryview(
            _TAG_CDR.pack(
                _CDR_LITTLE_ENDIAN,
                int(msg.tag_id),
                msg.x_tag_center_pixel,
                msg.y_tag_center_pixel,
                msg.closeness_metric,
            )
        )

    def decode(self, payload: bytes | memoryview) -> TagMessage:
        """Raises MessageDecodeError for anything but one well-formed tag message."""
        msg = deserialize(payload, self.type_name, MessageDecodeError, self._store)
        return TagMessage(
            int(msg.tag_id),
            float(msg.x_tag_center_pixel),
            float(msg.y_tag_center_pixel),
            float(msg.closeness_metric),
        )


def message_fields(msg: TagMessage) -> dict[str, float | int]:
    return {
        "tag_id": int(msg.tag_id),
        "x_tag_center_pixel": f32(msg.x_tag_center_pixel),
        "y_tag_center_pixel": f32(msg.y_tag_center_pixel),
        "closeness_metric": f32(msg.closeness_metric),
    }


def tag_entry(tag: TagObservation) -> dict[str, Any]:
    entry: dict[str, Any] = message_fields(tag.message())
    entry["corners"] = [[float(x), float(y)] for x, y in tag.corners]
    entry["metric"] = str(tag.metric)
    if tag.dictionary:
        entry["dictionary"] = tag.dictionary
    if tag.distance_m is not None:
        entry["distance_m"] = float(tag.distance_m)
    if tag.rvec is not None and tag.tvec is not None:
        entry["pose"] = {
            "rvec": list(tag.rvec),
            "tvec": list(tag.tvec),
            "quaternion": list(quaternion_from_rvec(tag.rvec)),
            "ambiguous": bool(tag.ambiguous),
        }
        if tag.pose_errors is not None:
            entry["pose"]["reprojection_px"] = [float(e) for e in tag.pose_errors]
    return entry


@dataclass(frozen=True, slots=True)
class FrameRecord:
    """Everything published on ``perception/tags`` for one frame."""

    stamp_ns: int
    frame_id: str
    seq: int
    width: int
    height: int
    selected: TagMessage
    tags: Sequence[TagObservation]
    timing_ms: Mapping[str, float]
    #: What the frame came as (the record's ``source``).
    source: InputKind
    #: The concrete key the frame came on (the record's ``stream``: a wildcard input has a
    #: stream per key).
    input_key: str = ""
    #: The Zenoh id of the service that answered.
    instance: str = ""
    #: Where ``tag`` was answered from the coarse first read and the whole frame's read
    #: selected another tag (or the same one more than half a pixel away): that selection.
    whole_selected: TagMessage | None = None

    def to_msgpack(self) -> bytes:
        record = {
            "stream": self.input_key,
            "instance": self.instance,
            "stamp_ns": int(self.stamp_ns),
            "frame_id": self.frame_id,
            "seq": int(self.seq),
            "width": int(self.width),
            "height": int(self.height),
            "source": self.source.value,
            "selected": message_fields(self.selected),
            "tags": [tag_entry(tag) for tag in self.tags],
            "timing": {key: round(float(value), 4) for key, value in self.timing_ms.items()},
        }
        if self.whole_selected is not None:
            record["whole_selected"] = message_fields(self.whole_selected)
        packed: bytes = msgpack.packb(record)
        return packed


_RECORD_KEYS: Final = (
    "stamp_ns",
    "frame_id",
    "seq",
    "width",
    "height",
    "selected",
    "tags",
    "timing",
)


_INT_KEYS: Final = ("stamp_ns", "seq", "width", "height")
#: Deepest nesting a record holds (``tags`` > tag > ``pose`` > ``rvec``), with room to spare.
_MAX_RECORD_DEPTH: Final = 8


def decode_record(payload: bytes | memoryview) -> dict[str, Any]:
    """Parse a ``perception/tags`` record and check what a consumer reads of it: the required
    keys, their types (``schemas/perception-tags.schema.json``) and that every number in it
    is finite, so that it prints as JSON.

    Raises:
        MessageDecodeError: with ``reason`` ``not_a_record`` (not msgpack, not a map),
            ``missing_field``, ``bad_field`` (a wrong type, or nested too deep) or
            ``non_finite`` (NaN or an infinity).

    """
    try:
        record = unpack_msgpack_map(payload, MessageDecodeError, "record")
    except MessageDecodeError as err:
        raise MessageDecodeError(str(err), reason="not_a_record") from err
    missing = [key for key in _RECORD_KEYS if key not in record]
    selected = record.get("selected")
    if not missing and isinstance(selected, dict):
        missing = [f"selected.{key}" for key in MESSAGE_FIELDS if key not in selected]
    if missing:
        text = f"record lacks {', '.join(missing)}"
        raise MessageDecodeError(text, reason="missing_field")
    _check_record(record)
    return record


def _bad(text: str) -> MessageDecodeError:
    return MessageDecodeError(text, reason="bad_field")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check_message(where: str, message: object) -> None:
    if not isinstance(message, dict):
        raise _bad(f"{where} is a {type(message).__name__}, not a map")
    for key in MESSAGE_FIELDS:
        value = message.get(key)
        if key == "tag_id" and not _is_int(value):
            raise _bad(f"{where}.tag_id is {value!r}, not an integer")
        if not _is_int(value) and not isinstance(value, float):
            raise _bad(f"{where}.{key} is {value!r}, not a number")


def _check_record(record: dict[Any, Any]) -> None:
    for key in _INT_KEYS:
        if not _is_int(record[key]):
            raise _bad(f"{key} is {record[key]!r}, not an integer")
    for key in ("frame_id", "stream", "instance"):  # the last two: services since streams
        if key in record and not isinstance(record[key], str):
            raise _bad(f"{key} is {record[key]!r}, not a string")
    _check_message("selected", record["selected"])
    if "whole_selected" in record:
        _check_message("whole_selected", record["whole_selected"])
    tags, timing = record["tags"], record["timing"]
    if not isinstance(tags, list):
        raise _bad(f"tags is {tags!r}, not an array")
    for index, tag in enumerate(tags):
        _check_message(f"tags[{index}]", tag)
    if not isinstance(timing, dict):
        raise _bad(f"timing is {timing!r}, not a map")
    for key, value in timing.items():
        if not isinstance(key, str) or not (_is_int(value) or isinstance(value, float)):
            raise _bad(f"timing.{key} is {value!r}, not a number")
    _check_json_ready("record", record, 0)


def _check_json_ready(where: str, value: object, depth: int) -> None:
    """``value`` is what JSON holds: maps with string keys, arrays, strings, integers,
    finite floats, booleans and nulls, at most :data:`_MAX_RECORD_DEPTH` deep."""
    if isinstance(value, float):
        if not math.isfinite(value):
            raise MessageDecodeError(f"{where} is {value}", reason="non_finite")
        return
    if value is None or isinstance(value, str | int):
        return
    if not isinstance(value, dict | list):
        raise _bad(f"{where} is a {type(value).__name__}, which JSON does not hold")
    if depth >= _MAX_RECORD_DEPTH:
        raise _bad(f"{where} nests deeper than {_MAX_RECORD_DEPTH} levels")
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise _bad(f"{where} has the key {key!r}, not a string")
            _check_json_ready(f"{where}.{key}", item, depth + 1)
    else:
        for index, item in enumerate(value):
            _check_json_ready(f"{where}[{index}]", item, depth + 1)
