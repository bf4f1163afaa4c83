"""Service counters, latency percentiles and a rate-limited log gate. Pure, thread-safe."""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


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
        }


class ServiceStats:
    """Counts frames and keeps the latencies of the last ``window`` processed frames."""

    def __init__(self, window: int = 1000, clock: Callable[[], float] = time.monotonic) -> None:
        self._lock = threading.Lock()
        self._clock = clock
        self._start = clock()
        self._latencies: deque[float] = deque(maxlen=window)
        self._done_at: deque[float] = deque(maxlen=window)
        self.received = 0
        self.processed = 0
        self.dropped = 0
        self._rejected: Counter[str] = Counter()

    def on_received(self, dropped_one: bool) -> None:
        with self._lock:
            self.received += 1
            if dropped_one:
                self.dropped += 1

    def on_rejected(self, reason: str) -> None:
        with self._lock:
            self._rejected[reason] += 1

    def on_processed(self, latency_ms: float) -> None:
        with self._lock:
            self.processed += 1
            self._latencies.append(latency_ms)
            self._done_at.append(self._clock())

    def snapshot(self) -> StatsSnapshot:
        with self._lock:
            now = self._clock()
            lat = np.fromiter(self._latencies, dtype=np.float64)
            recent = [t for t in self._done_at if now - t <= 5.0]
            fps = 0.0
            if len(recent) >= 2 and recent[-1] > recent[0]:
                fps = (len(recent) - 1) / (recent[-1] - recent[0])
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
            )


class LogGate:
    """At most one log line per key per ``interval`` s; reports how many were suppressed."""

    def __init__(self, interval: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._interval = interval
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
            self._last[key] = now
            return self._suppressed.pop(key, 0)
