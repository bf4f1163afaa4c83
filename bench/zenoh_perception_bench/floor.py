"""The transport floor: a bare Zenoh peer that does what the service must do with a frame and
nothing else. It copies each frame out of Zenoh and answers it at once on the tag key with a
no-tag ``StarterProjectTag`` and on the record key with an empty record of the same ``seq``.

The bench times it in lockstep beside the services, on the same camera and frames: a service's
own cost is its end-to-end time minus this one's. With ``--detect`` it is also OpenCV's default
bare, read in the callback before the answer (BGRA to grey and ``detectMarkers``, the least a
reader must do): the peer a user would write in a few lines, whose process idles between
frames exactly as the service's does. Run as
``python -m zenoh_perception_bench.floor -l ENDPOINT -e ENDPOINT --input-key K --tag-key K
--record-key K`` (other service flags are accepted and ignored); it runs until SIGTERM.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

import cv2
import msgpack
import numpy as np
import zenoh

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.tags.selection import NO_TAG
from zenoh_perception.wire.records import TagCodec
from zenoh_perception_bench._loopback import loopback_config

#: The record's timing fields, all zero: the floor does none of that work.
_TIMING = dict.fromkeys(("latency_ms", "queue_ms", "decode_ms", "convert_ms", "detect_ms"), 0.0)


def _meta(sample: zenoh.Sample) -> dict[str, Any]:
    """The frame's msgpack attachment ({} when there is none)."""
    attachment = sample.attachment
    if attachment is None:
        return {}
    meta: Any = msgpack.unpackb(attachment.to_bytes(), raw=False)
    return meta if isinstance(meta, dict) else {}


def _opencv(dictionary: str) -> Callable[[bytes, dict[str, Any]], None]:
    """OpenCV's default detector on a raw BGRA frame (its size from the attachment ``meta``)."""
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), cv2.aruco.DetectorParameters())

    def detect(pixels: bytes, meta: dict[str, Any]) -> None:
        if "width" not in meta:
            return
        image = np.frombuffer(pixels, np.uint8).reshape(int(meta["height"]), int(meta["width"]), 4)
        detector.detectMarkers(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY))

    return detect


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m zenoh_perception_bench.floor")
    parser.add_argument("-l", "--listen", action="append", default=[])
    parser.add_argument("-e", "--connect", action="append", default=[])
    parser.add_argument("--input-key", required=True)
    parser.add_argument("--tag-key", required=True)
    parser.add_argument("--record-key", required=True)
    parser.add_argument("--detect", action="store_true")
    parser.add_argument("--dictionary", default="DICT_4X4_50")
    args, _ignored = parser.parse_known_args(argv)
    detect = _opencv(args.dictionary) if args.detect else None
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    tag = bytes(TagCodec().encode(NO_TAG))
    with zenoh.open(loopback_config(listen=args.listen, connect=args.connect)) as session:
        tags = session.declare_publisher(args.tag_key)
        records = session.declare_publisher(args.record_key)

        def answer(sample: zenoh.Sample) -> None:
            pixels = sample.payload.to_bytes()  # the one copy out of Zenoh the service makes too
            meta = _meta(sample)
            if detect is not None:
                detect(pixels, meta)
            record = {"seq": int(meta.get("seq", -1)), "tags": [], "timing": _TIMING}
            tags.put(tag)
            records.put(msgpack.packb(record))

        # declared last: the bench waits for this subscriber to match before it starts
        session.declare_subscriber(args.input_key, answer)
        stop.wait()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
