"""``zenoh-perception echo``: print what the service publishes (``ros2 topic echo /tag`` here)."""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from typing import Any, TextIO

import zenoh

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.records import TagCodec, decode_record


def format_tag(key: str, payload: bytes, codec: TagCodec, *, as_json: bool) -> str:
    msg = codec.decode(payload)
    if as_json:
        return json.dumps(
            {
                "key": key,
                "tag_id": msg.tag_id,
                "x_tag_center_pixel": msg.x_tag_center_pixel,
                "y_tag_center_pixel": msg.y_tag_center_pixel,
                "closeness_metric": msg.closeness_metric,
            }
        )
    return (
        f"[{key}] tag_id={msg.tag_id} x={msg.x_tag_center_pixel:.2f} "
        f"y={msg.y_tag_center_pixel:.2f} closeness={msg.closeness_metric:.4f}"
    )


def format_record(key: str, payload: bytes, *, as_json: bool) -> str:
    record = decode_record(payload)
    if as_json:
        return json.dumps({"key": key, **record})
    ids = ",".join(str(tag.get("tag_id")) for tag in record["tags"]) or "-"
    latency = record["timing"].get("latency_ms", float("nan"))
    return (
        f"[{key}] seq={record['seq']} stamp_ns={record['stamp_ns']} "
        f"{record['width']}x{record['height']} tags={ids} "
        f"selected={record['selected']['tag_id']} latency_ms={latency:.2f}"
    )


def main(
    conf: zenoh.Config,
    *,
    tag_key: str = "tag",
    record_key: str = "perception/tags",
    ros_package: str = "mrover",
    records: bool = True,
    as_json: bool = False,
    count: int = 0,
    timeout: float | None = None,
    stop: threading.Event | None = None,
    out: TextIO = sys.stdout,
) -> int:
    """Print decoded tags (and records) until ``count`` lines, ``timeout`` or ``stop``.

    Returns 0, or 1 when ``count`` lines did not arrive before ``timeout``.
    """
    codec = TagCodec(ros_package)
    lines: queue.Queue[str] = queue.Queue()
    stop = stop or threading.Event()

    def on_tag(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            lines.put(format_tag(key, sample.payload.to_bytes(), codec, as_json=as_json))
        except MessageDecodeError as err:
            lines.put(f"[{key}] undecodable: {err}")

    def on_record(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            lines.put(format_record(key, sample.payload.to_bytes(), as_json=as_json))
        except MessageDecodeError as err:
            lines.put(f"[{key}] undecodable: {err}")

    with zenoh.open(conf) as session:
        subscribers: list[Any] = [session.declare_subscriber(tag_key, on_tag)]
        if records:
            subscribers.append(session.declare_subscriber(record_key, on_record))
        return _print_lines(lines, stop, out, count=count, timeout=timeout)


def _print_lines(
    lines: queue.Queue[str],
    stop: threading.Event,
    out: TextIO,
    *,
    count: int,
    timeout: float | None,
) -> int:
    deadline = None if timeout is None else time.monotonic() + timeout
    printed = 0
    while not stop.is_set():
        wait = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
        if wait <= 0:
            break
        try:
            line = lines.get(timeout=wait)
        except queue.Empty:
            continue
        print(line, file=out, flush=True)
        printed += 1
        if count and printed >= count:
            return 0
    return 1 if count and printed < count else 0
