"""The outputs as one line of text or JSON each: what ``echo`` and ``demo`` print."""

from __future__ import annotations

import json
import math
from typing import Any

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.wire.records import TagCodec, decode_record


def format_tag(key: str, payload: bytes, codec: TagCodec, *, as_json: bool) -> str:
    """One line for a ``tag`` message.

    Raises:
        MessageDecodeError: not one tag message, or a NaN or infinite field (``non_finite``).

    """
    msg = codec.decode(payload)
    for name in ("x_tag_center_pixel", "y_tag_center_pixel", "closeness_metric"):
        if not math.isfinite(getattr(msg, name)):
            text = f"{name} is {getattr(msg, name)}"
            raise MessageDecodeError(text, reason="non_finite")
    if as_json:
        return json.dumps(
            {
                "key": key,
                "tag_id": msg.tag_id,
                "x_tag_center_pixel": msg.x_tag_center_pixel,
                "y_tag_center_pixel": msg.y_tag_center_pixel,
                "closeness_metric": msg.closeness_metric,
            },
            allow_nan=False,
        )
    return (
        f"[{key}] tag_id={msg.tag_id} x={msg.x_tag_center_pixel:.2f} "
        f"y={msg.y_tag_center_pixel:.2f} closeness={msg.closeness_metric:.4f}"
    )


def format_decoded_record(key: str, record: dict[str, Any], *, as_json: bool) -> str:
    if as_json:
        # decode_record refused NaN and infinities: what is printed is JSON
        return json.dumps({"key": key, **record}, allow_nan=False)
    ids = ",".join(str(tag.get("tag_id")) for tag in record["tags"]) or "-"
    latency = record["timing"].get("latency_ms", float("nan"))
    return (
        f"[{key}] seq={record['seq']} stamp_ns={record['stamp_ns']} "
        f"{record['width']}x{record['height']} tags={ids} "
        f"selected={record['selected']['tag_id']} latency_ms={latency:.2f}"
    )


def format_record(key: str, payload: bytes, *, as_json: bool) -> str:
    return format_decoded_record(key, decode_record(payload), as_json=as_json)
