"""End to end: compressed camera frames (sensor_msgs/CompressedImage CDR, JPEG and PNG) into the
real ``zenoh-perception run``: good ones answered like raw frames, hostile ones (a PNG bomb, a
cut JPEG, an unknown format, corrupt bytes) each rejected and counted by reason."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import zenoh

from tests.helpers import (
    Collector,
    open_session,
    query_status,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tests.wire.test_compressed import compressed_cdr
from tests.wire.test_image_header import png_declaring
from zenoh_perception.wire.records import TagCodec, decode_record
from zenoh_perception_bench.scene import render_markers

W, H = 640, 480
KEY = "zed/left/image/compressed"
_BLOCK = zenoh.CongestionControl.BLOCK


def _square(x0: float, y0: float, side: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _encoded(ext: str) -> bytes:
    bgra = render_markers(W, H, [(3, _square(60, 80, 90)), (8, _square(330, 150, 200))])
    ok, data = cv2.imencode(ext, cv2.cvtColor(bgra, cv2.COLOR_BGRA2BGR))
    assert ok
    return bytes(data)


def _rejected(camera: zenoh.Session) -> dict[str, int]:
    status = query_status(camera)
    return {} if status is None else dict(status["rejected_by_reason"])


def test_run_answers_compressed_frames_and_counts_hostile_ones_by_reason(endpoint: str) -> None:
    jpeg, png = _encoded(".jpg"), _encoded(".png")
    hostile = [
        (png_declaring(16000, 16000), "png", "too_many_pixels"),  # a 768 MB bomb in 57 bytes
        (jpeg[: len(jpeg) // 2], "bgr8; jpeg compressed bgr8", "truncated_image"),
        (jpeg, "16UC1; compressedDepth png", "unsupported_image_format"),
        (jpeg, "tiff", "unsupported_image_format"),
        (b"\xff\xd8\xff" + bytes(range(256)) * 8 + b"\xff\xd9", "jpeg", "corrupt_image"),
        (b"\x00\x01\x00\x00\x01", "", "bad_compressed_cdr"),  # not a CompressedImage at all
    ]
    with (
        running_cli(
            "run", "-l", endpoint, "--no-multicast-scouting", "--stats-interval-s", "0"
        ) as proc,
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        tags = Collector(camera, "tag")
        records = Collector(camera, "perception/tags")
        publisher = camera.declare_publisher(KEY, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        codec = TagCodec()

        def answered(payload: bytes) -> dict[str, Any]:
            publisher.put(payload)
            assert codec.decode(tags.get(timeout=20).payload).tag_id == 8  # the larger tag
            return decode_record(records.get(timeout=20).payload)

        for i, (data, fmt) in enumerate([(jpeg, "rgb8; jpeg compressed bgr8"), (png, "png")]):
            record = answered(compressed_cdr(data, fmt, stamp_ns=1_000 + i, frame_id="zed_left"))
            assert (record["source"], record["stamp_ns"], record["frame_id"]) == (
                "compressed",
                1_000 + i,
                "zed_left",
            )
            assert (record["width"], record["height"]) == (W, H)
            assert sorted(tag["tag_id"] for tag in record["tags"]) == [3, 8]

        expected: dict[str, int] = {}
        for data, fmt, reason in hostile:
            payload = data if reason == "bad_compressed_cdr" else compressed_cdr(data, fmt)
            publisher.put(payload)
            expected[reason] = expected.get(reason, 0) + 1
            # one at a time: the mailbox never replaces one hostile frame with the next
            wait_until(lambda: _rejected(camera) == expected, 20, f"{reason} counted")
        # the service carries on
        answered(compressed_cdr(jpeg, "jpeg", stamp_ns=5, frame_id="zed_left"))
        assert tags.drain() == []  # nothing was answered for a rejected frame
        assert proc.poll() is None
    assert proc.returncode == 0


def test_the_compressed_input_is_off_with_an_empty_key(endpoint: str) -> None:
    with (
        running_cli(
            "run",
            "-l",
            endpoint,
            "--no-multicast-scouting",
            "--stats-interval-s",
            "0",
            "--compressed-input-key",
            "",
        ),
        open_session(connect=[endpoint]) as camera,
    ):
        status = wait_for_status(camera)
        assert status["settings"]["compressed_input_key"] == ""
        publisher = camera.declare_publisher(KEY)
        # the service is fully up (it answered its status) and declares no subscriber here
        matching: object = publisher.matching_status  # a MatchingStatus, whatever the stub says
        assert not getattr(matching, "matching", matching)
