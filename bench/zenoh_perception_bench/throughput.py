"""Throughput: frames published at a fixed rate to a service process; is every one processed?

HD1080 frames go at 60 Hz for a few seconds to each service process
(:mod:`~zenoh_perception_bench.processes`); every frame must be processed (none dropped by the
service's latest-frame-wins mailbox). Counts come from the service's status queryable,
latency (receive -> publish in the service) from its records. The service runs in a process
of its own, as deployed: in the bench's process, the camera, the consumer callbacks and the
service would share one interpreter (and its GIL), which a deployment never does.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, Final

import msgpack
import numpy as np
import zenoh

from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.framesets import Plan
from zenoh_perception_bench.processes import (
    E2E_DETECTORS,
    Camera,
    RawFrame,
    frames_of,
    quiet,
    raw_frames,
    services,
    settle,
)
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator
from zenoh_perception_bench.scoring import rounded

THROUGHPUT_RESOLUTION: Final = "HD1080"
THROUGHPUT_HZ: Final = 60.0


def throughput(
    detector: str,
    frames: Sequence[RawFrame],
    *,
    rate_hz: float,
    seconds: float,
    progress: Progress | None,
    label: str,
    shm: bool = True,
) -> dict[str, Any]:
    """Publish ``frames`` (cycled forward and back) at ``rate_hz`` for ``seconds`` to a service
    process; counts from its status queryable, latency (receive -> publish) from its records."""
    order = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))
    count = max(1, round(rate_hz * seconds))
    height, width = _frame_size(frames[0])
    camera = Camera(shm)
    bench_endpoint = loopback_endpoint()
    with (
        zenoh.open(loopback_config(listen=[bench_endpoint])) as session,
        services([detector], bench_endpoint, session) as remotes,
    ):
        remote = remotes[detector]
        remote.warm_up(width, height, camera)
        before = frames_of(quiet(remote))  # warm-up frames still in flight must not count
        remote.clear_records()
        start = time.perf_counter()
        late = 0
        for i in range(count):
            due = start + i / rate_hz
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.5 / rate_hz:
                late += 1
            frame = frames[order[i % len(order)]]
            remote.publisher.put(camera.load(frame.payload), attachment=frame.attachment)
            tick(progress, label)
        published_s = time.perf_counter() - start
        after = frames_of(settle(remote, before["received"] + count))
        latency = [float(r["timing"]["latency_ms"]) for r in remote.records()]
    processed = after["processed"] - before["processed"]
    return {
        "resolution": f"{width}x{height}",
        "rate_hz": rate_hz,
        "published": count,
        "publish_s": rounded(published_s),
        "late_puts": late,
        "received": after["received"] - before["received"],
        "processed": processed,
        "dropped": after["dropped"] - before["dropped"],
        # frames refused or abandoned at the frame deadline (a loaded machine): accounted for
        "rejected": after["rejected"] - before["rejected"],
        "processed_hz": rounded(processed / published_s if published_s > 0 else 0.0),
        "latency_p50_ms": rounded(np.percentile(latency, 50)) if latency else None,
        "latency_p99_ms": rounded(np.percentile(latency, 99)) if latency else None,
        "camera": camera.summary(),
    }


def _frame_size(frame: RawFrame) -> tuple[int, int]:
    meta = msgpack.unpackb(frame.attachment, raw=False)
    return int(meta["height"]), int(meta["width"])


def measure_throughput(plan: Plan, progress: Progress, *, shm: bool) -> dict[str, Any]:
    """:func:`throughput` of every service of :data:`E2E_DETECTORS` on an HD1080 drive at
    60 Hz for ``plan.throughput_s``."""
    generator = SceneGenerator(
        CameraModel.named(THROUGHPUT_RESOLUTION), seed=plan.seed + 30, effects=Effects.realistic()
    )
    count = max(2, min(90, round(THROUGHPUT_HZ * plan.throughput_s)))
    frames = raw_frames(generator.drive(count, fps=THROUGHPUT_HZ, n_tags=4, n_distractors=2))
    progress.step("throughput frames", 30)
    out: dict[str, Any] = {}
    for name in E2E_DETECTORS:
        out[name] = throughput(
            name,
            frames,
            rate_hz=THROUGHPUT_HZ,
            seconds=plan.throughput_s,
            progress=progress,
            label=f"60 Hz {name}",
            shm=shm,
        )
    return out
