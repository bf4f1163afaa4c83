"""The perception service: the thin layer that wires the pure pipeline to Zenoh.

Threads:

- Zenoh's callback threads only stamp the arrival time and drop the sample into a
  latest-frame-wins mailbox (O(1), no copy, no decoding).
- One worker thread copies the payload out of Zenoh once, decodes a zero-copy view, runs the
  pipeline and publishes ``tag`` then the record (and the debug image while it is watched).
- One reporter thread writes the periodic stats line.
"""

from __future__ import annotations

import gc
import json
import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import cv2
import zenoh

from zenoh_perception import __version__
from zenoh_perception.debug_image import annotate, encode_compressed_image
from zenoh_perception.detect.types import Detector
from zenoh_perception.errors import FrameDecodeError, MessageDecodeError
from zenoh_perception.frames import Frame, decode_image_cdr, decode_raw_frame, to_bgr
from zenoh_perception.logs import kv
from zenoh_perception.mailbox import LatestMailbox
from zenoh_perception.pipeline import Analysis, Pipeline
from zenoh_perception.pose import decode_camera_info
from zenoh_perception.records import FrameRecord, TagCodec
from zenoh_perception.settings import Settings
from zenoh_perception.stats import LogGate, ServiceStats

log = logging.getLogger("zenoh_perception.service")

MSGPACK_ENCODING = zenoh.Encoding("application/msgpack")
#: Rejection reason of a decoded frame the pipeline failed on (a detector bug, counted).
PROCESSING_ERROR = "processing_error"
_POLL_S = 0.1


@dataclass(frozen=True, slots=True)
class _Arrival:
    sample: zenoh.Sample
    received_ns: int  # monotonic clock
    wall_ns: int  # time since the epoch


class PerceptionService:
    """Subscribes frames on ``settings.input_key`` and publishes tags; see the module doc."""

    def __init__(
        self, session: zenoh.Session, settings: Settings, *, detector: Detector | None = None
    ) -> None:
        self.settings = settings
        self.stats = ServiceStats()
        self._session = session
        self._pipeline = Pipeline(settings, detector)
        self._codec = TagCodec(settings.ros_package)
        self._gate = LogGate(settings.log_interval_s)
        self._mailbox: LatestMailbox[_Arrival] = LatestMailbox()
        self._stop = threading.Event()
        #: Set when the worker thread died unexpectedly (the service then answers nothing).
        self.failed = threading.Event()
        self._debug_watched = threading.Event()
        self._last_debug = 0.0
        self._debug_images = 0
        self._seq = 0
        self._declared: list[Any] = []
        self._threads: list[threading.Thread] = []
        self._started = False

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> None:
        """Declare publishers, subscribers, the status queryable and the liveliness token."""
        if self._started:
            return
        self._started = True
        s, session = self.settings, self._session
        self._tag_pub = session.declare_publisher(
            s.tag_key, encoding=zenoh.Encoding.APPLICATION_CDR, express=True
        )
        self._record_pub = session.declare_publisher(
            s.record_key, encoding=MSGPACK_ENCODING, express=True
        )
        self._declared += [self._tag_pub, self._record_pub]
        self._debug_pub: zenoh.Publisher | None = None
        if s.debug_image:
            self._debug_pub = session.declare_publisher(
                s.debug_image_key, encoding=zenoh.Encoding.APPLICATION_CDR
            )
            listener = self._debug_pub.declare_matching_listener(self._on_debug_matching)
            self._declared += [listener, self._debug_pub]
        if s.camera_info_key:
            self._declared.append(
                session.declare_subscriber(s.camera_info_key, self._on_camera_info)
            )
        self._declared.append(session.declare_queryable(s.status_key, self._on_status_query))
        token_key = f"{s.liveliness_key}/{session.zid()}"
        self._declared.append(session.liveliness().declare_token(token_key))
        self._threads = [
            threading.Thread(target=self._work, name="perception-worker", daemon=True),
            threading.Thread(target=self._report, name="perception-stats", daemon=True),
        ]
        for thread in self._threads:
            thread.start()
        # Subscribe last: every frame that arrives finds the pipeline ready.
        self._declared.append(session.declare_subscriber(s.input_key, self._on_frame))
        log.info(
            "event=started %s",
            kv(
                version=__version__,
                zid=session.zid(),
                input=s.input_key,
                tag=s.tag_key,
                record=s.record_key,
                detector=s.detector,
                dictionary=s.dictionary,
                policy=s.policy,
                metric=s.metric,
            ),
        )

    def close(self) -> None:
        """Stop the worker, undeclare everything (the session itself is the caller's)."""
        self._stop.set()
        self._mailbox.close()
        for thread in self._threads:
            thread.join(timeout=2.0)
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except zenoh.ZError as err:  # session already closed
                log.debug("event=undeclare_failed %s", kv(error=err))
        self._declared.clear()
        log.info("event=stopped %s", kv(**self.stats.snapshot().as_dict()["frames"]))

    def __enter__(self) -> PerceptionService:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- Zenoh callbacks: O(1), never block ---------------------------------------------------

    def _on_frame(self, sample: zenoh.Sample) -> None:
        arrival = _Arrival(sample, time.monotonic_ns(), time.time_ns())
        self.stats.on_received(self._mailbox.put(arrival))

    def _on_debug_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            self._debug_watched.set()
        else:
            self._debug_watched.clear()
        log.info("event=debug_image watched=%s", status.matching)

    def _on_camera_info(self, sample: zenoh.Sample) -> None:
        try:
            intrinsics = decode_camera_info(sample.payload.to_bytes())
        except MessageDecodeError as err:
            self._reject("bad_camera_info", err)
            return
        if intrinsics != self._pipeline.intrinsics:
            self._pipeline.intrinsics = intrinsics
            log.info(
                "event=intrinsics fx=%.2f fy=%.2f cx=%.2f cy=%.2f",
                intrinsics.fx,
                intrinsics.fy,
                intrinsics.cx,
                intrinsics.cy,
            )

    def _on_status_query(self, query: zenoh.Query) -> None:
        query.reply(
            self.settings.status_key,
            json.dumps(self.status()),
            encoding=zenoh.Encoding.APPLICATION_JSON,
        )

    # -- worker ------------------------------------------------------------------------------

    def _work(self) -> None:
        try:
            while not self._stop.is_set():
                arrival = self._mailbox.take(_POLL_S)
                if arrival is not None:
                    self._handle(arrival)
        finally:
            if not self._stop.is_set():
                # Anything unforeseen: say so, and let run() exit non-zero rather than keep
                # a liveliness token that claims a service that answers nothing.
                log.error("event=worker_died")
                self.failed.set()

    def _handle(self, arrival: _Arrival) -> None:
        started = time.monotonic_ns()
        sample = arrival.sample
        payload = sample.payload.to_bytes()
        attachment = sample.attachment
        try:
            if attachment is not None:
                frame = decode_raw_frame(payload, attachment.to_bytes())
                source = "raw"
            else:
                frame = decode_image_cdr(payload)
                source = "cdr"
        except FrameDecodeError as err:
            self._reject(err.reason, err)
            return
        decoded = time.monotonic_ns()
        try:
            analysis = self._pipeline.process(frame)
        except (cv2.error, ValueError) as err:
            # A detector failing on one (valid) frame must not kill the worker: status and
            # liveliness would still say "alive" while no frame is ever answered again.
            self._reject(PROCESSING_ERROR, err)
            return
        self._tag_pub.put(bytes(self._codec.encode(analysis.selected)))
        published = time.monotonic_ns()
        latency_ms = (published - arrival.received_ns) / 1e6
        self._seq += 1
        record = FrameRecord(
            stamp_ns=frame.stamp_ns if frame.stamp_ns is not None else arrival.wall_ns,
            frame_id=frame.frame_id,
            seq=frame.seq if frame.seq is not None else self._seq,
            width=frame.width,
            height=frame.height,
            selected=analysis.selected,
            tags=analysis.tags,
            timing_ms={
                "latency_ms": latency_ms,
                "queue_ms": (started - arrival.received_ns) / 1e6,
                "decode_ms": (decoded - started) / 1e6,
                "convert_ms": analysis.convert_ms,
                "detect_ms": analysis.detect_ms,
            },
            source=source,
        )
        self._record_pub.put(record.to_msgpack())
        self.stats.on_processed(latency_ms)
        if self._debug_watched.is_set():
            self._publish_debug(frame, analysis, record.stamp_ns)

    def _publish_debug(self, frame: Frame, analysis: Analysis, stamp_ns: int) -> None:
        now = time.monotonic()
        if (
            self._debug_pub is None
            or now - self._last_debug < 1.0 / self.settings.debug_image_max_hz
        ):
            return
        self._last_debug = now
        image = annotate(to_bgr(frame), analysis.tags, analysis.selected)
        self._debug_pub.put(
            bytes(
                encode_compressed_image(
                    image,
                    quality=self.settings.debug_jpeg_quality,
                    stamp_ns=stamp_ns,
                    frame_id=frame.frame_id,
                )
            )
        )
        self._debug_images += 1

    def _reject(self, reason: str, err: Exception) -> None:
        self.stats.on_rejected(reason)
        suppressed = self._gate.admit(reason)
        if suppressed is not None:
            log.warning("event=rejected %s", kv(reason=reason, suppressed=suppressed, detail=err))

    # -- observability -----------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The JSON-ready status: counters, rates, latency and the effective settings."""
        snapshot = self.stats.snapshot().as_dict()
        return {
            "service": "zenoh-perception",
            "version": __version__,
            "zid": str(self._session.zid()),
            "worker_alive": not self.failed.is_set(),
            **snapshot,
            "debug_image": {
                "watched": self._debug_watched.is_set(),
                "published": self._debug_images,
            },
            "settings": self.settings.as_dict(),
        }

    def _report(self) -> None:
        interval = self.settings.stats_interval_s
        if interval <= 0:
            return
        while not self._stop.wait(interval):
            status = self.status()
            frames = status["frames"]
            latency = status["latency_ms"]
            log.info(
                "event=stats received=%d processed=%d dropped=%d rejected=%d fps=%.1f "
                "latency_p50_ms=%.2f latency_p99_ms=%.2f",
                frames["received"],
                frames["processed"],
                frames["dropped"],
                frames["rejected"],
                status["fps"],
                latency["p50"],
                latency["p99"],
            )


def open_session(
    conf: zenoh.Config, stop: threading.Event, retry_s: float = 1.0
) -> zenoh.Session | None:
    """``zenoh.open(conf)``; in client mode retried every ``retry_s`` until the router is up.

    Returns None when ``stop`` is set while waiting. Peer and router modes fail at once.
    """
    client = json.loads(conf.get_json("mode") or "null") == "client"
    while not stop.is_set():
        try:
            return zenoh.open(conf)
        except zenoh.ZError as err:
            if not client:
                raise
            log.warning("event=connect_failed %s", kv(retry_s=retry_s, error=err))
            stop.wait(retry_s)
    return None


def run(conf: zenoh.Config, settings: Settings, stop: threading.Event) -> int:
    """Serve until ``stop`` is set (exit code 0) or the worker dies (exit code 1)."""
    session = open_session(conf, stop)
    if session is None:
        return 0
    with session, PerceptionService(session, settings) as service:
        # What start-up made (modules, the OpenCV and Zenoh bindings, the pipeline) lives as
        # long as the process: out of the collector's way. A full collection that scans it
        # takes 12-15 ms, which at 60 Hz stalls a frame until the next one replaces another.
        gc.freeze()
        while not stop.wait(0.5):
            if service.failed.is_set():
                return 1
    return 0
