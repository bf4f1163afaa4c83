"""The streams a service serves, by name: made when a stream's first frame comes (at most
``max_streams``), forgotten when idle or released, each given the CameraInfo it is for.

A forgotten stream's counters stay in the service's totals, and its vetoes in
:attr:`StreamRegistry.retired_vetoes`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter

from zenoh_perception.pipeline import VETO_REASONS
from zenoh_perception.service.camera_infos import CameraInfos
from zenoh_perception.service.logs import kv
from zenoh_perception.service.stream import Shared, Stream

log = logging.getLogger(__name__)


class StreamRegistry:
    """The service's streams and the CameraInfos kept for them; thread-safe."""

    def __init__(self, shared: Shared) -> None:
        self._shared = shared
        self._streams: dict[str, Stream] = {}
        self._lock = threading.Lock()
        #: The CameraInfo subscription's callback and the infos kept for streams made later.
        self.camera_infos = CameraInfos(
            shared.settings.inputs,
            shared.totals,
            shared.gate,
            naming=shared.naming,
            streams=self._streams,
            lock=self._lock,
        )
        #: The vetoes of the streams forgotten, by reason.
        self.retired_vetoes: Counter[str] = Counter(dict.fromkeys(VETO_REASONS, 0))

    def open_at_start(self) -> None:
        """Make and open the streams known before any frame (a concrete input's one,
        ``""``): their outputs declared and their detectors' child processes ready."""
        for name in self._shared.naming.at_start:
            stream = Stream(name, self._shared)
            stream.open(start_detector=True)
            self._streams[name] = stream

    def serve(self, name: str) -> Stream | None:
        """The stream ``name``, made when new (None past ``max_streams``, or once stopped)."""
        stream = self._streams.get(name)
        if stream is not None:
            return stream
        with self._lock:
            stream = self._streams.get(name)
            if stream is None and not self._shared.stop.is_set():
                if len(self._streams) >= self._shared.naming.most_streams:
                    return None
                stream = self._streams[name] = Stream(name, self._shared)
                info = self.camera_infos.for_stream(name)
                if info is not None:
                    stream.use_camera_info(info)
            return stream

    def retire(self, name: str) -> None:
        """Forget stream ``name``: its counters stay in the totals, its vetoes too."""
        with self._lock:
            stream = self._streams.pop(name, None)
        if stream is None:
            return
        self.retired_vetoes.update(stream.vetoed)
        if self._shared.scheduler.remove(stream.lane):
            stream.close()  # else the worker holding it closes it
        log.info("event=stream_forgotten %s", kv(name=stream.name, stream=stream.input_key))

    def reap(self) -> None:
        """Forget the streams idle for ``stream_idle_s`` (but those known at start)."""
        horizon = time.monotonic_ns() - int(self._shared.settings.inputs.stream_idle_s * 1e9)
        kept = self._shared.naming.at_start
        with self._lock:
            idle = [
                name
                for name, s in self._streams.items()
                if s.last_ns < horizon and name not in kept
            ]
        for name in idle:
            self.retire(name)

    def all(self) -> list[Stream]:
        """The streams served now."""
        with self._lock:
            return list(self._streams.values())

    def by_key(self) -> list[Stream]:
        """The streams served now, sorted by key."""
        with self._lock:
            return sorted(self._streams.values(), key=lambda s: s.input_key)

    def guarded(self) -> list[Stream]:
        """The streams whose detection a deadline guards (the watchdog's)."""
        with self._lock:
            return [s for s in self._streams.values() if s.guard is not None]
