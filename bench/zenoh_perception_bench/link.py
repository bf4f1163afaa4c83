"""``bench --link``: raw HD frames against image_transport's JPEG, what each costs a link and
the service.

The same HD720 frames (realistic effects, 1-4 tags) go in lockstep, the order alternating per
frame, into one ``zenoh-perception run`` process: as sensor_msgs/Image CDR (BGRA8, what the
bridge delivers from a ZED node) on ``input_key``, and as sensor_msgs/CompressedImage CDR
(JPEG at image_transport's default quality, 95) on ``compressed_input_key``. Measured per
frame: the bytes each payload puts on a link, and put -> ``tag`` through Zenoh on loopback
(the decode, grey conversion and detection included). The Mbit/s at a camera rate and the
time a payload takes on a link of a given rate are arithmetic on the measured sizes, not a
radio measurement.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any, Final

import numpy as np
import zenoh

from zenoh_perception.wire.compressed import encode_compressed_frame
from zenoh_perception.wire.frames import decode_image_cdr, encode_image_cdr
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.overhead import frames_at
from zenoh_perception_bench.processes import Remote, ServiceProcess, _undeclare
from zenoh_perception_bench.runners import DICTIONARY

SERVICE: Final = "link"
#: image_transport's compressed plugin: ``jpeg_quality`` defaults to 95.
JPEG_QUALITY: Final = 95
RATES_HZ: Final = (15, 30, 60)
#: Link rates to show the time a frame takes on (Mbit/s): a congested radio, a good one,
#: gigabit Ethernet.
LINKS_MBIT: Final = (20, 100, 1000)
PATHS: Final = ("raw", "jpeg")


def payloads(images: list[Any]) -> list[dict[str, bytes]]:
    """Each frame as the two payloads a ROS camera publishes."""
    out = []
    for index, image in enumerate(images):
        raw = bytes(encode_image_cdr(image, "bgra8", stamp_ns=index + 1, frame_id="zed_left"))
        frame = decode_image_cdr(raw)
        jpeg = encode_compressed_frame(
            frame, "jpeg", stamp_ns=index + 1, frame_id="zed_left", jpeg_quality=JPEG_QUALITY
        )
        out.append({"raw": raw, "jpeg": bytes(jpeg)})
    return out


def lockstep(frames: list[dict[str, bytes]]) -> dict[str, list[float]]:
    """path -> put -> ``tag`` ms per frame, both paths into the same service process."""
    endpoint = loopback_endpoint()
    compressed_key = f"bench/{SERVICE}/image/compressed"
    times: dict[str, list[float]] = {path: [] for path in PATHS}
    service = ServiceProcess(
        SERVICE, "opencv", endpoint, DICTIONARY, ("--compressed-input-key", compressed_key)
    )
    with zenoh.open(loopback_config(listen=[endpoint])) as session:
        remote = Remote(session, service)
        jpeg_publisher = session.declare_publisher(
            compressed_key, congestion_control=zenoh.CongestionControl.BLOCK
        )
        publishers = {"raw": remote.publisher, "jpeg": jpeg_publisher}
        try:
            remote.wait_ready()
            for path in (*PATHS, *PATHS):  # warm-up: OpenCV's first calls on each path
                publishers[path].put(frames[0][path])
                remote.wait_answer()
            for index, frame in enumerate(frames):
                order = PATHS if index % 2 == 0 else PATHS[::-1]
                for path in order:
                    start = time.perf_counter()
                    publishers[path].put(frame[path])
                    times[path].append((remote.wait_answer() - start) * 1e3)
        finally:
            _undeclare(jpeg_publisher)
            remote.close()
            service.stop()
    return times


def summary(frames: list[dict[str, bytes]], times: dict[str, list[float]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for path in PATHS:
        size = float(np.median([len(f[path]) for f in frames]))
        out[path] = {
            "bytes_median": int(size),
            "mbit_s": {hz: round(size * 8 * hz / 1e6, 1) for hz in RATES_HZ},
            "link_ms": {mbit: round(size * 8 / (mbit * 1e6) * 1e3, 1) for mbit in LINKS_MBIT},
            "tag_median_ms": round(float(np.median(times[path])), 2),
            "tag_p90_ms": round(float(np.percentile(times[path], 90)), 2),
        }
    paired = [j / r for r, j in zip(times["raw"], times["jpeg"], strict=True)]
    out["jpeg_over_raw_median"] = round(float(np.median(paired)), 2)
    out["size_ratio"] = round(out["jpeg"]["bytes_median"] / out["raw"]["bytes_median"], 4)
    return out


def report(result: dict[str, Any], count: int) -> str:
    lines = [
        f"HD720, {count} frames, lockstep (order alternating), one service process, loopback",
        f"{'payload':<9}{'bytes':>10}"
        + "".join(f"{f'Mbit/s@{hz}':>13}" for hz in RATES_HZ)
        + "".join(f"{f'ms@{m}Mbit':>12}" for m in LINKS_MBIT)
        + f"{'tag med':>9}{'tag p90':>9}",
    ]
    for path in PATHS:
        r = result[path]
        lines.append(
            f"{path:<9}{r['bytes_median']:>10}"
            + "".join(f"{r['mbit_s'][hz]:>13}" for hz in RATES_HZ)
            + "".join(f"{r['link_ms'][m]:>12}" for m in LINKS_MBIT)
            + f"{r['tag_median_ms']:>9}{r['tag_p90_ms']:>9}"
        )
    lines.append(
        f"jpeg/raw: size {result['size_ratio']}, put -> tag {result['jpeg_over_raw_median']}x "
        "(median of per-frame ratios); ms@N Mbit = a frame's bytes on such a link (arithmetic)"
    )
    lines.append(f"load average {os.getloadavg()[0]:.1f}")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    count = args.frames or (6 if args.quick else 40)
    seed = args.seed if args.seed is not None else 2024
    frames = payloads(frames_at("HD720", count, seed))
    result = summary(frames, lockstep(frames))
    print(report(result, count))
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2))
    return 0
