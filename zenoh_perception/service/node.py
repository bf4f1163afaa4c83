"""The perception service: the thin layer that wires the pure pipeline to Zenoh.

Threads:

- Zenoh's callback threads only stamp the arrival time and drop the sample into a
  latest-frame-wins mailbox (O(1), no copy, no decoding).
- One worker thread checks the payload's size, copies it out of Zenoh once, decodes a
  zero-copy view, runs the pipeline up to the selected tag and publishes ``tag``, then lets
  the pipeline finish the frame (the veto's other detections) and publishes the record (and
  the debug image while it is watched).
- With ``frame_deadline_ms`` a frame the detector does not finish in time is abandoned (a
  rejection, counted with its time) and the newest frame read next by a fresh detector. By
  default (``detector_process = "on_stall"``) the worker detects in-process and a watchdog
  thread abandons a read past the deadline, leaves that worker to end on its own and starts
  another (:mod:`~zenoh_perception.service.guard`); for a while after, frames go to a child
  process that is killed on a stall (:mod:`~zenoh_perception.service.watchdog`), as every
  frame does with ``"always"``.
- One reporter thread writes the periodic stats line.

Everything the worker does with a sample, up to and including each publication, runs inside
its error handling: a bad payload is a rejection counted by reason, a failure of the
pipeline or of an encoder a ``processing_error`` counted by stage (a rejection too when it
happens before the tag is published), a failed publication a publish error counted by
output; the worker goes on with the next frame. Every repeating log line goes through one
rate limit (``log_interval_s``) per event and reason.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import struct
import threading
import time
from dataclasses import asdict, dataclass
from functools import partial
from typing import Any, Final

import cv2
import zenoh

from zenoh_perception import __version__
from zenoh_perception.detect.types import Detector
from zenoh_perception.errors import (
    CameraInfoError,
    FrameAbandonedError,
    FrameDecodeError,
    IntrinsicsError,
    ProcessingError,
    SessionError,
    SettingsError,
    zenoh_error_text,
)
from zenoh_perception.pipeline import Analysis, Pipeline, detector_for
from zenoh_perception.service.group import StreamGroup, StreamSubscriptions
from zenoh_perception.service.guard import GuardedDetector, StaleDetection
from zenoh_perception.service.logs import kv
from zenoh_perception.service.mailbox import LatestMailbox
from zenoh_perception.service.ros_outputs import RosOutputs
from zenoh_perception.service.ros_transport import RosTransport, TopicPublisher
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.service.watchdog import IsolatedDetector
from zenoh_perception.settings import Settings
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.wire.camera_info import check_camera_info_size, decode_camera_info
from zenoh_perception.wire.compressed import decode_compressed_cdr
from zenoh_perception.wire.debug_image import annotate, encode_compressed_image
from zenoh_perception.wire.frames import (
    Frame,
    check_payload_size,
    decode_image_cdr,
    decode_raw_frame,
    to_bgr,
)
from zenoh_perception.wire.records import FrameRecord, TagCodec

log = logging.getLogger("zenoh_perception.service.node")

MSGPACK_ENCODING = zenoh.Encoding("application/msgpack")
#: Rejection reason of a decoded frame the pipeline failed on (a detector bug, counted).
PROCESSING_ERROR = ProcessingError.reason
_POLL_S = 0.1
#: Zenoh configuration path of the largest message a session accepts.
MAX_MESSAGE_SIZE_PATH: Final = "transport/link/rx/max_message_size"
#: Room a frame message needs besides its payload: the attachment (at most 4 KiB), the key
#: and Zenoh's own headers.
MESSAGE_OVERHEAD_BYTES: Final = 8192

# What each stage may raise on a frame it cannot handle (OpenCV, rosbags' CDR serialiser,
# msgpack); anything else is a bug that stops the worker and makes ``run`` exit 1.
_DETECT_ERRORS: Final = (cv2.error, ValueError)
_ENCODE_ERRORS: Final = (struct.error, ValueError, OverflowError, TypeError)
_DEBUG_ERRORS: Final = (cv2.error, struct.error, ValueError, OverflowError)


@dataclass(frozen=True, slots=True)
class _Arrival:
    sample: zenoh.Sample
    received_ns: int  # monotonic clock
    wall_ns: int  # time since the epoch
    #: Came on an rmw_zenoh key: sensor_msgs/Image CDR, its attachment rmw_zenoh's own.
    ros_cdr: bool = False
    compressed: bool = False  # CompressedImage CDR (the compressed camera topic)


class PerceptionService:
    """Subscribes frames on ``settings.input_key`` and publishes tags; see the module doc."""

    def __init__(
        self, session: zenoh.Session, settings: Settings, *, detector: Detector | None = None
    ) -> None:
        self.settings = settings
        self.stats = ServiceStats(
            frame_budget_ms=settings.frame_budget_ms,
            frame_deadline_ms=settings.frame_deadline_ms or None,
        )
        self._session = session
        self._ros = RosTransport(session, settings)
        # Callbacks read the zid from here: asking the session while it closes raises.
        self._zid = str(session.zid())
        self._other_tokens = 0
        self._other_lock = threading.Lock()
        self._stop = threading.Event()
        # With a deadline the settings' detector is guarded (service/guard.py) or runs in a
        # child process (service/watchdog.py); a detector given here runs unguarded.
        self._isolated: IsolatedDetector | GuardedDetector | None = None
        self._guard: GuardedDetector | None = None
        if detector is None and settings.frame_deadline_ms > 0:
            factory, deadline_s = partial(detector_for, settings), settings.frame_deadline_ms / 1e3
            if settings.detector_process == "always":
                self._isolated = IsolatedDetector(factory, deadline_s, stop=self._stop)
            else:
                self._isolated = self._guard = GuardedDetector(factory, deadline_s, stop=self._stop)
            detector = self._isolated
        self._pipeline = Pipeline(settings, detector)
        self._camera_info: tuple[Intrinsics, tuple[int, int]] | None = None
        self._codec = TagCodec(settings.ros_package)
        self._ros_outputs = RosOutputs(settings)
        self._gate = LogGate(settings.log_interval_s)
        self._mailbox: LatestMailbox[_Arrival] = LatestMailbox()
        #: Set when the worker thread died unexpectedly (the service then answers nothing).
        self.failed = threading.Event()
        self._debug_watched = threading.Event()
        self._last_debug = 0.0
        self._debug_images = 0
        self._seq = 0
        self._tagless_since: float | None = None  # monotonic s; inf once the hint was given
        self._declared: list[Any] = []
        self._group: StreamGroup | None = None  # with share_group: the streams held
        self._threads: list[threading.Thread] = []
        self._workers: list[threading.Thread] = []
        self._started = False

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> None:
        """Declare publishers, subscribers, the status queryable and the liveliness token.

        Raises:
            SessionError: Zenoh refused a declaration (e.g. the session is closed).

        """
        if self._started:
            return
        self._started = True
        try:
            self._declare()
        except zenoh.ZError as err:
            msg = f"cannot declare the service's keys: {zenoh_error_text(err)}"
            raise SessionError(msg) from err
        log.info(
            "event=started %s",
            kv(
                version=__version__,
                zid=self._session.zid(),
                ros_transport=self.settings.ros_transport,
                input=self._ros.key("camera") if self.settings.input_key else "",
                compressed_input=(
                    self._ros.key("compressed_camera") if self.settings.compressed_input_key else ""
                ),
                tag=self._tag_pub.key,
                record=self.settings.record_key,
                detector=self.settings.detector,
                dictionary=self.settings.dictionary,
                policy=self.settings.policy,
                metric=self.settings.metric,
                max_frame_bytes=self.settings.max_frame_bytes,
                max_frame_pixels=self.settings.max_frame_pixels,
            ),
        )

    def _declare(self) -> None:
        s, session = self.settings, self._session
        if self._isolated is not None:
            self._isolated.start()
        node_token = self._ros.declare_node()
        if node_token is not None:
            self._declared.append(node_token)
        self._tag_pub = self._ros.publisher("tag", express=True)
        self._record_pub = session.declare_publisher(
            s.record_key, encoding=MSGPACK_ENCODING, express=True
        )
        self._declared += [self._tag_pub, self._record_pub, *self._ros_outputs.declare(self._ros)]
        self._debug_pub: TopicPublisher | None = None
        if s.debug_image:
            self._debug_pub = self._ros.publisher("debug_image")
            listener = self._debug_pub.declare_matching_listener(self._on_debug_matching)
            self._declared += [listener, self._debug_pub]
        if s.camera_info_key:
            self._declared.append(self._ros.subscribe("camera_info", self._on_camera_info))
        self._declared.append(session.declare_queryable(s.status_key, self._on_status_query))
        token_key = f"{s.liveliness_key}/{session.zid()}"
        self._declared.append(session.liveliness().declare_token(token_key))
        # another service under the same liveliness key, there now or later, is reported:
        # two services on the same keys publish every tag twice
        self._declared.append(
            session.liveliness().declare_subscriber(
                f"{s.liveliness_key}/*", self._on_service_token, history=True
            )
        )
        self._threads = [
            threading.Thread(target=self._report, name="perception-stats", daemon=True)
        ]
        if self._guard is not None:
            self._threads.append(
                threading.Thread(target=self._watch, name="perception-watchdog", daemon=True)
            )
        for thread in self._threads:
            thread.start()
        self._start_worker()
        # Subscribe last: every frame that arrives finds the pipeline ready.
        on_camera, on_compressed = self._on_frame, self._on_compressed_frame
        if self._ros.rmw_zenoh:
            # raw frames (msgpack attachment) keep coming on the plain key
            if s.input_key:
                self._declared.append(session.declare_subscriber(s.input_key, self._on_frame))
            on_camera = self._on_ros_frame
        if s.share_group:
            # only the announced streams this instance is given, each on its concrete key
            held = StreamSubscriptions(
                session, {s.input_key: on_camera, s.compressed_input_key: on_compressed}
            )
            self._group = StreamGroup(
                session,
                name=s.share_group,
                liveliness_key=s.liveliness_key,
                patterns=held.patterns,
                take=held.take,
                release=held.release,
            )
            self._group.start()
            return
        if s.input_key:
            self._declared.append(self._ros.subscribe("camera", on_camera))
        if s.compressed_input_key:
            self._declared.append(self._ros.subscribe("compressed_camera", on_compressed))

    def close(self) -> None:
        """Stop the worker, undeclare everything (the session itself is the caller's)."""
        if self._group is not None:  # its streams first: the others take them once it is gone
            self._group.close()
        self._stop.set()
        self._mailbox.close()
        # A worker inside OpenCV is not waited for, nor one abandoned before: each ends on
        # its own (daemon threads).
        stuck = self._guard.abandon() if self._guard is not None else None
        current = self._workers[-1:]
        for thread in [*self._threads, *(w for w in current if w.ident != stuck)]:
            thread.join(timeout=2.0)
        if self._isolated is not None:
            self._isolated.close()
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

    def _on_ros_frame(self, sample: zenoh.Sample) -> None:
        arrival = _Arrival(sample, time.monotonic_ns(), time.time_ns(), ros_cdr=True)
        self.stats.on_received(self._mailbox.put(arrival))

    def _on_compressed_frame(self, sample: zenoh.Sample) -> None:
        arrival = _Arrival(sample, time.monotonic_ns(), time.time_ns(), compressed=True)
        self.stats.on_received(self._mailbox.put(arrival))

    def _on_debug_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            self._debug_watched.set()
        else:
            self._debug_watched.clear()
        self._log_limited(logging.INFO, "debug_image", "debug_image", watched=status.matching)

    def _on_service_token(self, sample: zenoh.Sample) -> None:
        """Another perception service's liveliness token appeared (ours is left out).

        Anyone may declare tokens under the key: one rate limit for the event, whatever the
        name, and only a count kept.
        """
        other = str(sample.key_expr).rsplit("/", 1)[-1]
        if self._stop.is_set() or sample.kind != zenoh.SampleKind.PUT or other == self._zid:
            return
        if self.settings.share_group:
            return  # the members of a group share the keys by design, one holder a stream
        with self._other_lock:
            self._other_tokens += 1
        self._log_limited(
            logging.WARNING,
            "another_service",
            "another_service",
            zid=other,
            liveliness=str(sample.key_expr),
            tag=self.settings.tag_key,
            detail="another perception service runs here; on the same keys every tag and "
            "record is published twice: give each its own keys",
        )

    def _on_camera_info(self, sample: zenoh.Sample) -> None:
        try:
            check_camera_info_size(len(sample.payload))  # before the copy out of Zenoh
            info = decode_camera_info(sample.payload.to_bytes())
        except (CameraInfoError, IntrinsicsError) as err:
            # Counted apart from frames: a bad CameraInfo is no frame, and the intrinsics in
            # use stay as they were.
            self.stats.on_camera_info(err.reason)
            self._log_limited(
                logging.WARNING,
                f"camera_info:{err.reason}",
                "camera_info_rejected",
                reason=err.reason,
                detail=err,
            )
            return
        self.stats.on_camera_info(None)
        intrinsics = info.intrinsics
        if (intrinsics, (info.width, info.height)) != self._camera_info:
            self._camera_info = (intrinsics, (info.width, info.height))
            self._pipeline.use_camera_info(intrinsics, info.width, info.height)
            # A camera whose intrinsics change on every message would flood the log: the
            # line is rate-limited and the status always shows the intrinsics in use.
            self._log_limited(
                logging.INFO,
                "intrinsics",
                "intrinsics",
                fx=f"{intrinsics.fx:.2f}",
                fy=f"{intrinsics.fy:.2f}",
                cx=f"{intrinsics.cx:.2f}",
                cy=f"{intrinsics.cy:.2f}",
                width=info.width,
                height=info.height,
            )

    def _on_status_query(self, query: zenoh.Query) -> None:
        try:
            query.reply(
                self.settings.status_key,
                json.dumps(self.status()),
                encoding=zenoh.Encoding.APPLICATION_JSON,
            )
        except zenoh.ZError as err:  # the querier or the session went away
            self._log_limited(
                logging.DEBUG, "status_reply", "status_reply_failed", error=zenoh_error_text(err)
            )

    # -- worker ------------------------------------------------------------------------------

    def _start_worker(self) -> None:
        worker = threading.Thread(target=self._work, name="perception-worker", daemon=True)
        # only the current worker and the abandoned ones still running are kept
        self._workers = [w for w in self._workers if w.is_alive()] + [worker]
        worker.start()

    def _work(self) -> None:
        replaced = False
        try:
            while not self._stop.is_set():
                arrival = self._mailbox.take(_POLL_S)
                if arrival is not None:
                    self._handle(arrival)
        except StaleDetection:
            # The watchdog abandoned this thread's frame and another worker took over: end
            # without touching anything else.
            replaced = True
        finally:
            if not replaced and not self._stop.is_set():
                # Anything unforeseen: say so, and let run() exit non-zero rather than keep
                # a liveliness token that claims a service that answers nothing.
                log.error("event=worker_died")
                self.failed.set()

    def _handle(self, arrival: _Arrival) -> None:
        try:
            self._process(arrival)
        except FrameDecodeError as err:
            self._reject(err.reason, err)
        except FrameAbandonedError as err:
            # No tag and no record for it; the detector was restarted for the next frame.
            self.stats.on_abandoned(err.elapsed_ms)
            self._reject(err.reason, err)
        except ProcessingError as err:
            # Failed before the tag was published: the frame is rejected.
            self.stats.on_processing_error(err.stage)
            self._reject(err.reason, err)

    def _process(self, arrival: _Arrival) -> None:
        """Decode, analyse and publish one frame.

        Raises:
            FrameDecodeError: the payload is refused (its ``reason`` is counted).
            ProcessingError: the frame could not be analysed or its tag encoded.

        """
        started = time.monotonic_ns()
        s = self.settings
        sample = arrival.sample
        # The size is known before the one copy out of Zenoh: an oversized frame costs nothing.
        check_payload_size(len(sample.payload), s.max_frame_bytes)
        payload = sample.payload.to_bytes()
        attachment = sample.attachment
        if arrival.compressed:
            # colour only for a watched debug image; the detector reads grey
            frame = decode_compressed_cdr(
                payload, max_pixels=s.max_frame_pixels, grey=not self._debug_watched.is_set()
            )
            source = "compressed"
        elif attachment is not None and not arrival.ros_cdr:
            frame = decode_raw_frame(payload, attachment.to_bytes(), max_pixels=s.max_frame_pixels)
            source = "raw"
        else:
            frame = decode_image_cdr(payload, max_pixels=s.max_frame_pixels)
            source = "cdr"
        decoded = time.monotonic_ns()
        try:
            # the selected tag first: the verifier judges the other detections after its put
            pending = self._pipeline.begin(frame)
        except _DETECT_ERRORS as err:
            # A detector failing on one (valid) frame must not kill the worker: status and
            # liveliness would still say "alive" while no frame is ever answered again.
            raise ProcessingError("detect", err) from err
        # counted before any output is out: whoever reads one may ask the status next
        if pending.intrinsics_mismatch:
            self.stats.on_intrinsics_mismatch()
            self._log_limited(
                logging.WARNING,
                "intrinsics_mismatch",
                "intrinsics_mismatch",
                frame=f"{frame.width}x{frame.height}",
                detail="the CameraInfo in use is for another image size: its intrinsics are "
                "left out for this frame",
            )
        try:
            tag = bytes(self._codec.encode(pending.selected))
        except _ENCODE_ERRORS as err:
            raise ProcessingError("encode_tag", err) from err
        self._publish(self._tag_pub, "tag", tag)
        published = time.monotonic_ns()
        # From here on the frame is answered: later failures are counted, not rejections.
        try:
            analysis = pending.finish()
        except _DETECT_ERRORS as err:
            self._processing_failed(ProcessingError("detect", err))
            return
        latency_ms = (published - arrival.received_ns) / 1e6
        decode_ms = (decoded - started) / 1e6
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
                "decode_ms": decode_ms,
                "convert_ms": analysis.convert_ms,
                "detect_ms": analysis.detect_ms,
            },
            source=source,
        )
        try:
            self._publish(self._record_pub, "record", record.to_msgpack())
        except _ENCODE_ERRORS as err:
            self._processing_failed(ProcessingError("encode_record", err))
        self._publish_ros_outputs(analysis, record.stamp_ns, frame.frame_id)
        self.stats.on_processed(
            latency_ms,
            frame_ms=decode_ms + analysis.convert_ms + analysis.detect_ms,
            detect_ms=analysis.detect_ms,
        )
        self._hint_if_tagless(bool(analysis.tags))
        if self._debug_watched.is_set():
            try:
                self._publish_debug(frame, analysis, record.stamp_ns)
            except ProcessingError as err:
                self._processing_failed(err)

    def _watch(self) -> None:
        """Abandon an in-process detection past the deadline, and start another worker."""
        guard = self._guard
        assert guard is not None  # the thread runs only with a guard
        while not self._stop.wait(guard.poll_s()):
            elapsed_ms = guard.check()
            if elapsed_ms is None:
                continue
            err = FrameAbandonedError(elapsed_ms, guard.deadline_s * 1e3)
            self.stats.on_abandoned(elapsed_ms)
            self._reject(err.reason, err)
            self._start_worker()

    def _hint_if_tagless(self, tagged: bool) -> None:
        """Once ``no_tag_hint_s`` of frames all had no tag, say what to check (once, until a
        tag is seen again)."""
        now = time.monotonic()
        if tagged or self.settings.no_tag_hint_s <= 0:
            self._tagless_since = None
            return
        if self._tagless_since is None:
            self._tagless_since = now
        elif now - self._tagless_since >= self.settings.no_tag_hint_s:
            self._tagless_since = math.inf  # said: quiet until a tag is seen again
            log.info(
                "event=no_tag_hint %s",
                kv(
                    seconds=self.settings.no_tag_hint_s,
                    dictionary=self.settings.dictionary,
                    detail="no tag in any frame: if tags are in view, run `zenoh-perception "
                    "probe` on a recording of this camera to find their dictionary",
                ),
            )

    def _publish_ros_outputs(self, analysis: Analysis, stamp_ns: int, frame_id: str) -> None:
        """Every detection and the tags' transforms (see service/ros_outputs.py)."""
        encoded, failed = self._ros_outputs.encode(analysis, stamp_ns=stamp_ns, frame_id=frame_id)
        for err in failed:
            self._processing_failed(err)
        for output in encoded:
            self._publish(output.publisher, output.name, output.payload)

    def _publish_debug(self, frame: Frame, analysis: Analysis, stamp_ns: int) -> None:
        """Annotate, encode and publish the debug image (at most ``debug_image_max_hz``).

        Raises:
            ProcessingError: drawing or encoding failed (stage ``debug_image``).

        """
        now = time.monotonic()
        if (
            self._debug_pub is None
            or now - self._last_debug < 1.0 / self.settings.debug_image_max_hz
        ):
            return
        self._last_debug = now
        try:
            image = annotate(
                to_bgr(frame),
                analysis.tags,
                analysis.selected,
                intrinsics=self._pipeline.intrinsics,
                tag_size=self.settings.tag_size_for,
            )
            payload = bytes(
                encode_compressed_image(
                    image,
                    quality=self.settings.debug_jpeg_quality,
                    stamp_ns=stamp_ns,
                    frame_id=frame.frame_id,
                )
            )
        except _DEBUG_ERRORS as err:
            raise ProcessingError("debug_image", err) from err
        if self._publish(self._debug_pub, "debug_image", payload):
            self._debug_images += 1

    def _publish(
        self, publisher: TopicPublisher | zenoh.Publisher, output: str, payload: bytes
    ) -> bool:
        """Put ``payload``; a failure is counted by ``output`` and logged (rate-limited)."""
        try:
            publisher.put(payload)
        except zenoh.ZError as err:
            self.stats.on_publish_error(output)
            self._log_limited(
                logging.WARNING,
                f"publish:{output}",
                "publish_failed",
                output=output,
                error=zenoh_error_text(err),
            )
            return False
        return True

    def _processing_failed(self, err: ProcessingError) -> None:
        self.stats.on_processing_error(err.stage)
        self._log_limited(
            logging.WARNING,
            f"processing:{err.stage}",
            "processing_error",
            stage=err.stage,
            detail=err,
        )

    def _reject(self, reason: str, err: Exception) -> None:
        self.stats.on_rejected(reason)
        suppressed = self._gate.admit(reason)
        if suppressed is not None:
            log.warning("event=rejected %s", kv(reason=reason, suppressed=suppressed, detail=err))

    def _log_limited(self, level: int, key: str, event: str, **fields: object) -> None:
        """Log ``event`` at most once per ``log_interval_s`` for ``key``, saying how many
        lines were left out since the last one."""
        suppressed = self._gate.admit(key)
        if suppressed is not None:
            log.log(level, "event=%s %s", event, kv(**fields, suppressed=suppressed))

    # -- observability -----------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The JSON-ready status: counters, rates, latency and the effective settings."""
        snapshot = self.stats.snapshot().as_dict()
        intrinsics = self._pipeline.intrinsics
        snapshot["camera_info"]["intrinsics"] = None if intrinsics is None else asdict(intrinsics)
        return {
            "service": "zenoh-perception",
            "version": __version__,
            "zid": self._zid,
            "worker_alive": not self.failed.is_set(),
            **snapshot,
            "liveliness": {"other_services": self._other_tokens},
            "group": None if self._group is None else self._group.status(),
            "vetoed_by_reason": dict(self._pipeline.vetoed),
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
            if frames["received"] == 0:
                # a line of zeros says nothing: say what is awaited, and where
                log.info(
                    "event=waiting_for_frames %s",
                    kv(key=self.settings.input_key, detail="no frame received yet"),
                )
                continue
            latency = status["latency_ms"]
            budget = status["budget"]
            log.info(
                "event=stats received=%d processed=%d dropped=%d rejected=%d fps=%.1f "
                "latency_p50_ms=%.2f latency_p99_ms=%.2f over_budget=%d detect_ms_max=%.2f "
                "abandoned=%d abandoned_ms_max=%.2f publish_errors=%d processing_errors=%d",
                frames["received"],
                frames["processed"],
                frames["dropped"],
                frames["rejected"],
                status["fps"],
                latency["p50"],
                latency["p99"],
                budget["over_budget"],
                budget["detect_ms_max"],
                budget["abandoned"],
                budget["abandoned_ms_max"],
                sum(status["publish_errors"].values()),
                sum(status["processing_errors"].values()),
            )


def open_session(
    conf: zenoh.Config, stop: threading.Event, retry_s: float = 1.0, log_interval_s: float = 5.0
) -> zenoh.Session | None:
    """``zenoh.open(conf)``; in client mode retried every ``retry_s`` until the router is up
    (the retry line is logged at most once per ``log_interval_s``).

    Returns None when ``stop`` is set while waiting.

    Raises:
        SessionError: peer and router modes, at once (e.g. a listen port in use).

    """
    client = json.loads(conf.get_json("mode") or "null") == "client"
    gate = LogGate(log_interval_s)
    while not stop.is_set():
        try:
            return zenoh.open(conf)
        except zenoh.ZError as err:
            text = zenoh_error_text(err)
            if not client:
                msg = f"cannot open the Zenoh session: {text}"
                raise SessionError(msg) from err
            suppressed = gate.admit("connect_failed")
            if suppressed is not None:
                fields = kv(retry_s=retry_s, suppressed=suppressed, error=text)
                log.warning("event=connect_failed %s", fields)
            stop.wait(retry_s)
    return None


def check_transport_limit(conf: zenoh.Config, settings: Settings) -> None:
    """Refuse a ``max_frame_bytes`` that the session's own message limit would drop.

    Raises:
        SettingsError: ``max_frame_bytes`` plus the message overhead exceeds Zenoh's
            ``transport/link/rx/max_message_size``.

    """
    try:
        limit = int(json.loads(conf.get_json(MAX_MESSAGE_SIZE_PATH)))
    except (zenoh.ZError, ValueError, TypeError):
        return  # a Zenoh without that setting: nothing to compare with
    if settings.max_frame_bytes + MESSAGE_OVERHEAD_BYTES > limit:
        msg = (
            f"max_frame_bytes = {settings.max_frame_bytes} does not fit Zenoh's "
            f"{MAX_MESSAGE_SIZE_PATH} = {limit} (a frame message needs "
            f"{MESSAGE_OVERHEAD_BYTES} bytes more): lower max_frame_bytes or raise it with "
            f"--cfg '{MAX_MESSAGE_SIZE_PATH}:N' here and on every router in between"
        )
        raise SettingsError(msg)


def run(conf: zenoh.Config, settings: Settings, stop: threading.Event) -> int:
    """Serve until ``stop`` is set (exit code 0) or the worker dies (exit code 1).

    Raises:
        SettingsError: ``max_frame_bytes`` exceeds the Zenoh configuration's message limit.
        SessionError: the Zenoh session cannot be opened or the service's keys declared.

    """
    check_transport_limit(conf, settings)
    session = open_session(conf, stop, log_interval_s=settings.log_interval_s)
    if session is None:
        return 0
    endpoints = _connect_endpoints(conf)
    with session, PerceptionService(session, settings) as service:
        # What start-up made (modules, the OpenCV and Zenoh bindings, the pipeline) lives as
        # long as the process: out of the collector's way. A full collection that scanned it
        # would delay the frame in progress, at a high frame rate long enough for the next
        # frame to replace a waiting one (a drop).
        gc.freeze()
        check_at = time.monotonic() + CONNECT_WARNING_S if endpoints else math.inf
        while not stop.wait(0.5):
            if service.failed.is_set():
                return 1
            if time.monotonic() >= check_at:
                check_at = math.inf
                if not _linked(session):
                    log.warning(
                        "event=unreachable %s",
                        kv(
                            connect=",".join(endpoints),
                            after_s=CONNECT_WARNING_S,
                            detail="no peer or router reached through the endpoints to connect "
                            "to; Zenoh keeps trying",
                        ),
                    )
    return 0


#: Seconds after start at which ``run`` warns that none of its connect endpoints answered.
CONNECT_WARNING_S = 5.0


def _connect_endpoints(conf: zenoh.Config) -> list[str]:
    """The endpoints the configuration tells the session to connect to."""
    value = json.loads(conf.get_json("connect/endpoints"))
    if isinstance(value, dict):  # per-mode endpoints
        value = [e for endpoints in value.values() for e in endpoints]
    return [str(e) for e in value] if isinstance(value, list) else []


def _linked(session: zenoh.Session) -> bool:
    """Whether the session has reached at least one peer or router."""
    info = session.info
    return bool(list(info.peers_zid()) or list(info.routers_zid()))
