"""Samples a consumer (``echo``, ``demo``'s printer) could not decode: skipped and counted."""

from __future__ import annotations

import json
import threading
from collections import Counter

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.service.stats import LogGate

#: Seconds between two lines for the same reason of undecodable samples.
SKIP_LINE_INTERVAL_S = 5.0


class Skipped:
    """Samples that could not be decoded, counted by key and reason; one line per reason at
    most every ``interval`` s says so (with how many were left out). Thread-safe."""

    def __init__(self, interval: float = SKIP_LINE_INTERVAL_S) -> None:
        self.counts: Counter[tuple[str, str]] = Counter()
        self._gate = LogGate(interval)
        self._lock = threading.Lock()

    def skip(self, key: str, error: MessageDecodeError, *, as_json: bool) -> str | None:
        """Count ``error``; the line to print about it, or None while rate-limited."""
        with self._lock:
            self.counts[key, error.reason] += 1
        suppressed = self._gate.admit(f"{key}\0{error.reason}")
        if suppressed is None:
            return None
        if as_json:
            skipped = {"reason": error.reason, "detail": str(error), "suppressed": suppressed}
            return json.dumps({"key": key, "skipped": skipped})
        more = f" ({suppressed} more since the last line)" if suppressed else ""
        return f"[{key}] undecodable, skipped ({error.reason}): {error}{more}"

    def summary(self) -> str:
        with self._lock:
            total = sum(self.counts.values())
            by = " ".join(f"{k}:{r}={n}" for (k, r), n in sorted(self.counts.items()))
        return f"skipped={total}" + (f" {by}" if by else "")
