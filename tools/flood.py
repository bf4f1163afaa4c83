"""Camera flood: frames far faster than the service processes them, then one marked frame.

``python -m tools.flood --resolution HD720 --ratio 8 --count 240`` starts the
service in this process (loopback peers, no multicast), measures its processing time, floods
frames at ``ratio`` times its processing rate and then checks what a rover needs:

- memory stays bounded (RSS after the flood versus after a warm-up burst);
- no backlog: at the end of the flood at most two frames wait (the one in progress and the
  newest), and a marked frame (its own tag id and seq) sent then is answered after at most the
  one in progress. To make that count exact, the worker is held inside one frame
  (:class:`HoldableDetector`) for the flood's last quarter;
- every frame is accounted for: ``received == processed + dropped + rejected`` with
  ``dropped > 0``.

Its building blocks (marker frames, a camera, a listener, status counts) are in
:mod:`tools.rig`.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import zenoh

from tools.rig import STATUS_KEY, Camera, Listener, marker_frame, proc_sample, wait_status
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.service.status import query_status
from zenoh_perception.settings import Settings
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import frames_of, is_idle

# -- the load check ------------------------------------------------------------------------------


class HoldableDetector(Detector):
    """Wraps a detector; after :meth:`hold` the next ``detect`` waits until :meth:`release`.

    The load check holds the service's worker inside one frame while the flood's tail and the
    marked frame arrive, so "how many frames are answered before the marked one" does not
    depend on thread timing.
    """

    def __init__(self, inner: Detector, *, max_hold_s: float = 60.0) -> None:
        self._inner = inner
        self._max_hold_s = max_hold_s
        self._released = threading.Event()
        self._released.set()
        self.holding = threading.Event()

    def hold(self) -> None:
        self.holding.clear()
        self._released.clear()

    def release(self) -> None:
        self._released.set()

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        if not self._released.is_set():
            self.holding.set()
            self._released.wait(self._max_hold_s)
        return self._inner.detect(gray)


@dataclass(frozen=True, slots=True)
class LoadConfig:
    resolution: str = "HD720"
    ratio: float = 8.0  # flood rate / processing rate
    count: int = 240  # flood frames
    warmup: int = 5  # frames sent one at a time to measure the processing time
    max_rate_hz: float = 2000.0
    flood_tag: int = 3
    marked_tag: int = 9
    timeout_s: float = 60.0


@dataclass(slots=True)
class LoadReport:
    resolution: str
    frame_bytes: int
    processing_ms: float  # median service latency of warm-up frames sent one at a time
    target_rate_hz: float
    flood_frames: int
    flood_s: float
    rss_before_kib: int  # after a warm-up burst
    rss_after_kib: int  # at the end of the flood (worker held, marked frame waiting)
    dropped_before_hold: int  # dropped during the flood while the worker ran freely
    waiting_after_flood: int  # frames received but not yet handled, at the end of the flood
    stale_frames: int  # frames processed after the flood, before the marked one (counters)
    stale_records: int  # records answered after the flood, before the marked one's
    marked_tag_id: int
    expected_tag_id: int
    marked_center: tuple[float, float]
    expected_center: tuple[float, float]
    status: dict[str, Any] = field(default_factory=dict)

    @property
    def achieved_rate_hz(self) -> float:
        return self.flood_frames / self.flood_s if self.flood_s > 0 else 0.0

    @property
    def rss_growth_kib(self) -> int:
        return self.rss_after_kib - self.rss_before_kib

    def problems(self, max_growth_frames: float = 16.0) -> list[str]:
        """What is wrong (empty: the service coped): memory, backlog, accounting, answer."""
        out: list[str] = []
        bound_kib = max_growth_frames * self.frame_bytes / 1024
        if self.rss_growth_kib > bound_kib:
            out.append(
                f"RSS grew {self.rss_growth_kib} KiB over the flood (> {bound_kib:.0f} KiB, "
                f"{max_growth_frames:g} frames)"
            )
        if self.waiting_after_flood > 2:
            out.append(f"backlog: {self.waiting_after_flood} frames waiting after the flood")
        if self.stale_frames > 1 or self.stale_records > 1:
            out.append(
                f"backlog: {self.stale_frames} stale frames ({self.stale_records} records) "
                "answered before the marked frame"
            )
        if self.marked_tag_id != self.expected_tag_id:
            out.append(f"marked frame answered tag {self.marked_tag_id}")
        f = frames_of(self.status)
        if self.dropped_before_hold <= 0:
            out.append("no frame dropped: the flood did not outrun the service")
        if not is_idle(self.status):
            out.append(f"frames unaccounted for: {f}")
        return out

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["achieved_rate_hz"] = round(self.achieved_rate_hz, 1)
        data["rss_growth_kib"] = self.rss_growth_kib
        return data


def _pace(start: float, index: int, rate_hz: float) -> None:
    delay = start + index / rate_hz - time.monotonic()
    if delay > 0:
        time.sleep(delay)


def _waiting(status: dict[str, Any]) -> int:
    f = frames_of(status)
    return f["received"] - f["processed"] - f["dropped"] - f["rejected"]


def run_load(
    session: zenoh.Session,
    gate: HoldableDetector,
    config: LoadConfig = LoadConfig(),
    *,
    rss_kib: Callable[[], int] = lambda: proc_sample().rss_kib,
) -> LoadReport:
    """Flood the service reachable through ``session`` (whose detector is ``gate``).

    1. Frames one at a time give the processing time; a warm-up burst brings Zenoh's buffers
       and the allocator to their working size; RSS is read.
    2. ``count`` frames at ``ratio`` times the processing rate. For the last quarter the worker
       is held inside one frame; then a marked frame (its own tag id and seq) is sent and RSS
       read again: every frame is in, and at most two may wait (the held one and the newest).
    3. Released, the service must answer the marked frame after at most the held one.

    ``rss_kib`` reads the memory to watch (default: this process, where an in-process service
    lives). The service must be idle and use the default keys.
    """
    width, height = RESOLUTIONS[config.resolution]
    # Four backgrounds in turn: a moving scene, which a tracking detector cannot shortcut.
    floods = [
        marker_frame(width, height, config.flood_tag, clutter=True, seed=seed)
        for seed in range(10, 14)
    ]
    side = max(60, min(width, height) // 4)
    marked = marker_frame(
        width, height, config.marked_tag, clutter=True, seed=2, origin=(side // 2, side // 2)
    )
    camera = Camera(session)
    listener = Listener(session)
    gate.release()
    try:
        camera.wait_matched()
        wait_status(session, lambda s: True, timeout=config.timeout_s, what="an answer")
        processing: list[float] = []
        seq = 1_000_000
        for i in range(config.warmup):
            seq += 1
            camera.put(floods[i % len(floods)], seq)
            record, _before = listener.record_for(seq, config.timeout_s)
            processing.append(float(record["timing"]["latency_ms"]))  # idle: no queueing
        processing_ms = statistics.median(processing)
        rate = min(config.max_rate_hz, config.ratio * 1000.0 / max(processing_ms, 0.1))
        sent = config.warmup

        dropped_before_hold: list[int] = []

        def flood_burst(count: int, first_seq: int, hold_at: int | None = None) -> float:
            start = time.monotonic()
            for i in range(count):
                if i == hold_at:
                    replies = query_status(session, STATUS_KEY, timeout=1.0, gather=False)
                    dropped_before_hold.append(frames_of(replies[0])["dropped"] if replies else 0)
                    gate.hold()
                _pace(start, i, rate)
                camera.put(floods[i % len(floods)], first_seq + i)
            return time.monotonic() - start

        def settle(total: int) -> dict[str, Any]:
            return wait_status(
                session,
                lambda s: frames_of(s)["received"] >= total and is_idle(s),
                timeout=config.timeout_s,
                what=f"{total} frames received and handled",
            )

        burst = max(10, config.count // 4)
        flood_burst(burst, 2_000_000)
        sent += burst
        dropped_after_warmup = frames_of(settle(sent))["dropped"]
        rss_before = rss_kib()

        flood_s = flood_burst(config.count, 0, hold_at=config.count * 3 // 4)
        sent += config.count
        if not gate.holding.wait(config.timeout_s):
            msg = "the service's worker never reached the held detector"
            raise TimeoutError(msg)
        marked_seq = 3_000_000
        camera.put(marked, marked_seq)
        sent += 1
        held = wait_status(
            session,
            lambda s: frames_of(s)["received"] >= sent,
            timeout=config.timeout_s,
            what=f"{sent} frames received",
        )
        rss_after = rss_kib()
        listener.drain()
        gate.release()

        record, before = listener.record_for(marked_seq, config.timeout_s)
        final = settle(sent)
        selected = record["selected"]
        return LoadReport(
            resolution=config.resolution,
            frame_bytes=len(floods[0].payload),
            processing_ms=processing_ms,
            target_rate_hz=rate,
            flood_frames=config.count,
            flood_s=flood_s,
            rss_before_kib=rss_before,
            rss_after_kib=rss_after,
            dropped_before_hold=dropped_before_hold[0] - dropped_after_warmup,
            waiting_after_flood=_waiting(held),
            stale_frames=frames_of(final)["processed"] - frames_of(held)["processed"] - 1,
            stale_records=sum(1 for a in before if a.record is not None),
            marked_tag_id=int(selected["tag_id"]),
            expected_tag_id=config.marked_tag,
            marked_center=(
                float(selected["x_tag_center_pixel"]),
                float(selected["y_tag_center_pixel"]),
            ),
            expected_center=marked.center,
            status=final,
        )
    finally:
        gate.release()
        listener.close()
        camera.close()


# -- command line ---------------------------------------------------------------------------------


def main(config: LoadConfig, *, as_json: bool = False) -> int:
    """Flood a service started in this process and print what it did; 1 when a check fails."""
    endpoint = loopback_endpoint()
    settings = Settings.from_flat(stats_interval_s=0.0)
    gate = HoldableDetector(
        make_detector(settings.detection.detector, settings.detection.dictionary)
    )
    with (
        zenoh.open(loopback_config(listen=[endpoint])) as service_session,
        PerceptionService(service_session, settings, detector=gate),
        zenoh.open(loopback_config(connect=[endpoint])) as camera_session,
    ):
        report = run_load(camera_session, gate, config)
    problems = report.problems()
    if as_json:
        print(json.dumps({**report.as_dict(), "problems": problems}, indent=2))
    else:
        f = frames_of(report.status)
        print(
            f"{report.resolution}: processing {report.processing_ms:.1f} ms/frame, flood "
            f"{report.flood_frames} frames at {report.achieved_rate_hz:.0f} Hz "
            f"({report.achieved_rate_hz * report.processing_ms / 1000:.1f}x processing)\n"
            f"RSS {report.rss_before_kib / 1024:.1f} -> {report.rss_after_kib / 1024:.1f} MiB; "
            f"frames {f} ({report.dropped_before_hold} dropped before the hold); after the "
            f"flood {report.waiting_after_flood} frame(s) waiting, "
            f"{report.stale_frames} stale frame(s) answered before the marked one"
        )
        for problem in problems:
            print(f"PROBLEM: {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        prog="python -m tools.flood", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--resolution", choices=sorted(RESOLUTIONS), default="HD720")
    parser.add_argument("--ratio", type=float, default=8.0, help="flood rate / processing rate")
    parser.add_argument("--count", type=int, default=240, help="frames in the flood")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    args = parser.parse_args()
    config = LoadConfig(resolution=args.resolution, ratio=args.ratio, count=args.count)
    sys.exit(main(config, as_json=args.json))
