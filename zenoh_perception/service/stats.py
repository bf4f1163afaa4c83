"""Service counters, latency percentiles and a rate-limited log gate. Pure, thread-safe."""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np

#: Outputs whose publication failures are counted (see ``ServiceStats.on_publish_error``).
OUTPUTS: Final = ("tag", "record", "debug_image", "detections", "tf")
#: Wall-time window of the frame rate, seconds.
FPS_WINDOW_S: Final = 5.0


@dataclass(frozen=True, slots=True)
class StatsSnapshot:
    uptime_s: float
    received: int
    processed: int
    dropped: int
    rejected: dict[str, int]
    fps: float
    latency_p50_ms: float
    latency_p99_ms: float
    latency_mean_ms: float
    frame_budget_ms: float | None = None
    over_budget: int = 0
    frame_ms_max: float = 0.0
    detect_ms_max: float = 0.0
    frame_deadline_ms: float | None = None
    abandoned: int = 0
    abandoned_ms_max: float = 0.0
    abandoned_ms_last: float = 0.0
    publish_errors: dict[str, int] = field(default_factory=dict)
    processing_errors: dict[str, int] = field(default_factory=dict)
    camera_info_received: int = 0
    camera_info_rejected: dict[str, int] = field(default_factory=dict)
    intrinsics_mismatch: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "uptime_s": round(self.uptime_s, 3),
            "frames": {
                "received": self.received,
                "processed": self.processed,
                "dropped": self.dropped,
                "rejected": sum(self.rejected.values()),
            },
            "rejected_by_reason": dict(self.rejected),
            "fps": round(self.fps, 3),
            "latency_ms": {
                "p50": round(self.latency_p50_ms, 3),
                "p99": round(self.latency_p99_ms, 3),
                "mean": round(self.latency_mean_ms, 3),
            },
            "budget": {
                "frame_budget_ms": self.frame_budget_ms,
                "over_budget": self.over_budget,
                "frame_ms_max": round(self.frame_ms_max, 3),
                "detect_ms_max": round(self.detect_ms_max, 3),
                "frame_deadline_ms": self.frame_deadline_ms,
                "abandoned": self.abandoned,
                "abandoned_ms_max": round(self.abandoned_ms_max, 3),
                "abandoned_ms_last": round(self.abandoned_ms_last, 3),
            },
            "publish_errors": {name: self.publish_errors.get(name, 0) for name in OUTPUTS},
            "processing_errors": dict(self.processing_errors),
            "camera_info": {
                "received": self.camera_info_received,
                "rejected_by_reason": dict(self.camera_info_rejected),
                "size_mismatch_frames": self.intrinsics_mismatch,
            },
        }


class ServiceStats:
    """Counts frames and keeps the latencies of the last ``window`` processed frames.

    ``fps`` is frames over wall time: the frames finished within the last ``fps_window_s``
    seconds divided by that window (or by the uptime while it is shorter). A frame whose own
    time (decode, convert, detect) exceeds ``frame_budget_ms`` (None: no budget) counts as
    over budget. A frame the detector did not finish within ``frame_deadline_ms`` is
    abandoned: counted with how long it ran (and rejected, by the caller).

    A stream's counters have the service's as ``parent``: every event counted here is
    counted there too, so the service's totals outlive the streams it forgets.
    """

    def __init__(
        self,
        window: int = 1000,
        clock: Callable[[], float] = time.monotonic,
        *,
        frame_budget_ms: float | None = None,
        frame_deadline_ms: float | None = None,
        fps_window_s: float = FPS_WINDOW_S,
        parent: ServiceStats | None = None,
    ) -> None:
        self._parent = parent
        self._lock = threading.Lock()
        self._clock = clock
        self._start = clock()
        self._latencies: deque[float] = deque(maxlen=window)
        # Finish times within the fps window: as many as frames finish in that window.
        self._done_at: deque[float] = deque()
        self._fps_window_s = fps_window_s
        self._frame_budget_ms = frame_budget_ms
        self._frame_deadline_ms = frame_deadline_ms
        self._abandoned = 0
        self._abandoned_ms_max = 0.0
        self._abandoned_ms_last = 0.0
        self.received = 0
        self.processed = 0
        self.dropped = 0
        self._rejected: Counter[str] = Counter()
        self._over_budget = 0
        self._frame_ms_max = 0.0
        self._detect_ms_max = 0.0
        self._publish_errors: Counter[str] = Counter()
        self._processing_errors: Counter[str] = Counter()
        self._camera_info_received = 0
        self._camera_info_rejected: Counter[str] = Counter()
        self._intrinsics_mismatch = 0

    def on_received(self, dropped_one: bool) -> None:
        if self._parent is not None:
            self._parent.on_received(dropped_one)
        with self._lock:
            self.received += 1
            if dropped_one:
                self.dropped += 1

    def on_rejected(self, reason: str) -> None:
        if self._parent is not None:
            self._parent.on_rejected(reason)
        with self._lock:
            self._rejected[reason] += 1

    def on_processed(
        self, latency_ms: float, *, frame_ms: float = 0.0, detect_ms: float = 0.0
    ) -> None:
        """One frame published; ``frame_ms`` is its own time (decode, convert, detect) and
        ``detect_ms`` the detector's share."""
        if self._parent is not None:
            self._parent.on_processed(latency_ms, frame_ms=frame_ms, detect_ms=detect_ms)
        with self._lock:
            now = self._clock()
            self.processed += 1
            self._latencies.append(latency_ms)
            self._done_at.append(now)
            self._forget_before(now)
            self._frame_ms_max = max(self._frame_ms_max, frame_ms)
            self._detect_ms_max = max(self._detect_ms_max, detect_ms)
            if self._frame_budget_ms is not None and frame_ms > self._frame_budget_ms:
                self._over_budget += 1

    def on_abandoned(self, elapsed_ms: float) -> None:
        """One frame given up after ``elapsed_ms`` of detection."""
        if self._parent is not None:
            self._parent.on_abandoned(elapsed_ms)
        with self._lock:
            self._abandoned += 1
            self._abandoned_ms_last = elapsed_ms
            self._abandoned_ms_max = max(self._abandoned_ms_max, elapsed_ms)

    def on_publish_error(self, output: str) -> None:
        if self._parent is not None:
            self._parent.on_publish_error(output)
        with self._lock:
            self._publish_errors[output] += 1

    def on_processing_error(self, stage: str) -> None:
        if self._parent is not None:
            self._parent.on_processing_error(stage)
        with self._lock:
            self._processing_errors[stage] += 1

    def on_camera_info(self, rejected_reason: str | None) -> None:
        """One CameraInfo sample, rejected for ``rejected_reason`` (None: accepted)."""
        if self._parent is not None:
            self._parent.on_camera_info(rejected_reason)
        with self._lock:
            self._camera_info_received += 1
            if rejected_reason is not None:
                self._camera_info_rejected[rejected_reason] += 1

    def on_intrinsics_mismatch(self) -> None:
        """One frame not of the size of the CameraInfo in use (its intrinsics left out)."""
        if self._parent is not None:
            self._parent.on_intrinsics_mismatch()
        with self._lock:
            self._intrinsics_mismatch += 1

    def _forget_before(self, now: float) -> None:
        horizon = now - self._fps_window_s
        while self._done_at and self._done_at[0] <= horizon:
            self._done_at.popleft()

    def snapshot(self) -> StatsSnapshot:
        with self._lock:
            now = self._clock()
            lat = np.fromiter(self._latencies, dtype=np.float64)
            self._forget_before(now)
            span = min(self._fps_window_s, now - self._start)
            fps = len(self._done_at) / span if span > 0 else 0.0
            if lat.size:
                p50, p99 = (float(v) for v in np.percentile(lat, [50, 99]))
                mean = float(lat.mean())
            else:
                p50 = p99 = mean = 0.0
            return StatsSnapshot(
                uptime_s=now - self._start,
                received=self.received,
                processed=self.processed,
                dropped=self.dropped,
                rejected=dict(self._rejected),
                fps=fps,
                latency_p50_ms=p50,
                latency_p99_ms=p99,
                latency_mean_ms=mean,
                frame_budget_ms=self._frame_budget_ms,
                over_budget=self._over_budget,
                frame_ms_max=self._frame_ms_max,
                detect_ms_max=self._detect_ms_max,
                frame_deadline_ms=self._frame_deadline_ms,
                abandoned=self._abandoned,
                abandoned_ms_max=self._abandoned_ms_max,
                abandoned_ms_last=self._abandoned_ms_last,
                publish_errors=dict(self._publish_errors),
                processing_errors=dict(self._processing_errors),
                camera_info_received=self._camera_info_received,
                camera_info_rejected=dict(self._camera_info_rejected),
                intrinsics_mismatch=self._intrinsics_mismatch,
            )


#: Keys a :class:`LogGate` remembers at most (keys are events and reasons, a fixed set).
LOG_GATE_KEYS: Final = 256


class LogGate:
    """At most one log line per key per ``interval`` s; reports how many were suppressed.

    It remembers at most ``max_keys`` keys: past that, the oldest is forgotten (its next line
    is let through), so no stream of new keys grows it for good.
    """

    def __init__(
        self,
        interval: float,
        clock: Callable[[], float] = time.monotonic,
        *,
        max_keys: int = LOG_GATE_KEYS,
    ) -> None:
        self._interval = interval
        self._max_keys = max_keys
        self._clock = clock
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()
        self._lock = threading.Lock()

    def admit(self, key: str) -> int | None:
        """None to stay quiet; else the number of lines suppressed since the last one."""
        with self._lock:
            now = self._clock()
            last = self._last.get(key)
            if last is not None and now - last < self._interval:
                self._suppressed[key] += 1
                return None
            self._last.pop(key, None)  # re-inserted last: the dict is oldest first
            self._last[key] = now
            while len(self._last) > self._max_keys:
                oldest = next(iter(self._last))
                del self._last[oldest]
                self._suppressed.pop(oldest, None)
            return self._suppressed.pop(key, 0)
