"""One stream: one camera's frames, detector state, intrinsics, deadline, statistics and
outputs.

A concrete ``input_key`` is one stream; a wildcard one (``cams/*/image``) is a stream per
concrete key it matches, named by the chunks its wildcards matched, and a list of keys a
stream per key (or per key an entry matches), named by the chunks where the entries differ
(:mod:`~zenoh_perception.wire.stream_keys`), whose outputs are the output keys with
``{stream}`` replaced by that name. Nothing of a stream is shared with another but the
session, the codec, the log rate limit and a publisher two streams' keys name alike (a TF
key without ``{stream}``): a marker seen on one camera never confirms, vetoes or carries
over to another's frame.

Its newest frame waits in its :class:`~zenoh_perception.service.mailbox.Lane`; one worker
at a time runs :meth:`Stream.handle` on it: checks the payload's size, copies it out of
Zenoh once, decodes a zero-copy view, runs the pipeline up to the selected tag and publishes
``tag``, then lets the pipeline finish the frame (the veto's other detections) and publishes
the record (and the ROS outputs, and the debug image while it is watched).

Everything it does with a frame, up to and including each publication, runs inside its
error handling: a bad payload is a rejection counted by reason, a failure of the pipeline or
of an encoder a ``processing_error`` counted by stage (a rejection too when it happens before
the tag is published), a failed publication a publish error counted by output.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
import time
from dataclasses import asdict, dataclass, field
from functools import partial
from typing import Any, Final

import cv2
import zenoh

from zenoh_perception.detect.types import Detector
from zenoh_perception.errors import (
    FrameAbandonedError,
    FrameDecodeError,
    ProcessingError,
    zenoh_error_text,
)
from zenoh_perception.pipeline import Analysis, Pipeline, detector_for
from zenoh_perception.service.guard import GuardedDetector
from zenoh_perception.service.logs import kv
from zenoh_perception.service.mailbox import Lane, Scheduler
from zenoh_perception.service.ros_outputs import RosOutputs
from zenoh_perception.service.ros_transport import RosTransport, TopicPublisher
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.service.watchdog import IsolatedDetector
from zenoh_perception.settings import Settings
from zenoh_perception.tags.pose import Intrinsics
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
from zenoh_perception.wire.stream_keys import stream_key

log = logging.getLogger("zenoh_perception.service.node")

MSGPACK_ENCODING = zenoh.Encoding("application/msgpack")

# What each stage may raise on a frame it cannot handle (OpenCV, rosbags' CDR serialiser,
# msgpack); anything else is a bug that stops the worker and makes ``run`` exit 1.
_DETECT_ERRORS: Final = (cv2.error, ValueError)
_ENCODE_ERRORS: Final = (struct.error, ValueError, OverflowError, TypeError)
_DEBUG_ERRORS: Final = (cv2.error, struct.error, ValueError, OverflowError)

#: Intrinsics of a CameraInfo and the image size they are for.
CameraInfo = tuple[Intrinsics, tuple[int, int]]


@dataclass(frozen=True, slots=True)
class Arrival:
    """A frame as Zenoh's callback left it: the sample, untouched, and when it came."""

    sample: zenoh.Sample
    received_ns: int  # monotonic clock
    wall_ns: int  # time since the epoch
    #: Came on an rmw_zenoh key: sensor_msgs/Image CDR, its attachment rmw_zenoh's own.
    ros_cdr: bool = False
    compressed: bool = False  # CompressedImage CDR (the compressed camera topic)


class Publishers:
    """The streams' publishers by key: streams whose keys are alike (a TF key without
    ``{stream}``) share one, undeclared when the last of them is closed. Thread-safe."""

    def __init__(self, session: zenoh.Session, ros: RosTransport) -> None:
        self._session = session
        self._ros = ros
        self._lock = threading.Lock()
        self._held: dict[str, tuple[TopicPublisher, int]] = {}

    def ros(self, role: str, stream: str, *, express: bool) -> TopicPublisher:
        """The publisher of ROS topic ``role`` for ``stream``."""
        return self._acquire(
            self._ros.key(role, stream),
            lambda: self._ros.publisher(role, express=express, stream=stream),
        )

    def record(self, key: str) -> TopicPublisher:
        """The publisher of the msgpack record on ``key``."""
        return self._acquire(
            key,
            lambda: TopicPublisher(
                self._session.declare_publisher(key, encoding=MSGPACK_ENCODING, express=True)
            ),
        )

    def _acquire(self, key: str, declare: Any) -> TopicPublisher:
        with self._lock:
            held = self._held.get(key)
            publisher: TopicPublisher = held[0] if held is not None else declare()
            self._held[key] = (publisher, (held[1] if held is not None else 0) + 1)
            return publisher

    def release(self, publisher: TopicPublisher) -> None:
        """One holder less; undeclared with the last.

        Raises:
            zenoh.ZError: Zenoh refused the undeclaration (the session closed).

        """
        with self._lock:
            publisher_held, count = self._held[publisher.key]
            if count > 1:
                self._held[publisher.key] = (publisher_held, count - 1)
                return
            del self._held[publisher.key]
        publisher.undeclare()


@dataclass(frozen=True, slots=True)
class Shared:
    """What the service gives every stream."""

    settings: Settings
    session: zenoh.Session
    ros: RosTransport
    publishers: Publishers
    scheduler: Scheduler[Stream, Arrival]
    codec: TagCodec
    gate: LogGate
    totals: ServiceStats  # the service's counters: each stream's are counted there too
    instance: str  # the service's Zenoh id, in every record
    stop: threading.Event
    #: A detector for every stream (tests): unguarded, shared.
    detector: Detector | None = None
    #: Lines name the stream (a wildcard input: several streams).
    named: bool = field(default=False)


class _StreamPublishers:
    """A stream's view of :class:`Publishers`, for :class:`RosOutputs`."""

    def __init__(self, publishers: Publishers, stream: str) -> None:
        self._publishers = publishers
        self._stream = stream

    def publisher(self, role: str, *, express: bool = False) -> TopicPublisher:
        return self._publishers.ros(role, self._stream, express=express)


class Stream:
    """One camera's frames and everything the service keeps for them; see the module doc.

    Built in Zenoh's callback thread (cheap: counters and a lane); :meth:`open` (the first
    worker to take its frame, or the service at start for a concrete input) builds the
    pipeline and declares the outputs.
    """

    def __init__(self, name: str, shared: Shared) -> None:
        s = shared.settings
        self.name = name
        self.key = ""  # the concrete key the last frame came on
        self._shared = shared
        self.stats = ServiceStats(
            frame_budget_ms=s.frame_budget_ms,
            frame_deadline_ms=s.frame_deadline_ms or None,
            parent=shared.totals,
        )
        self.lane: Lane[Stream, Arrival] = shared.scheduler.lane(self)
        self.last_ns = time.monotonic_ns()  # the last frame's arrival
        self.opened = False
        self.worker: int | None = None  # the thread answering its frame (threading.get_ident)
        self.guard: GuardedDetector | None = None
        self._isolated: IsolatedDetector | GuardedDetector | None = None
        self._pipeline: Pipeline | None = None
        self._camera_info: CameraInfo | None = None
        self._declared: list[TopicPublisher] = []
        self._listener: Any = None
        self._subscription: zenoh.LivelinessToken | None = None
        self._tag_pub: TopicPublisher | None = None
        self._record_pub: TopicPublisher | None = None
        self._debug_pub: TopicPublisher | None = None
        self._ros_outputs = RosOutputs(s)
        self.debug_watched = threading.Event()
        self._last_debug = 0.0
        self.debug_images = 0
        self._seq = 0
        self._tagless_since: float | None = None  # monotonic s; inf once the hint was given
        self._open_lock = threading.Lock()

    # -- life cycle -------------------------------------------------------------------------

    def open(self, *, start_detector: bool = False) -> None:
        """Build the pipeline (with a deadline, guarded: :mod:`~zenoh_perception.service.
        guard`) and declare the outputs; ``start_detector`` starts the guard's child
        processes now (else at the first stall).

        Raises:
            zenoh.ZError: Zenoh refused a declaration.

        """
        with self._open_lock:
            if self.opened:
                return
            shared, s = self._shared, self._shared.settings
            detector = shared.detector
            if detector is None and s.frame_deadline_ms > 0:
                factory, deadline_s = partial(detector_for, s), s.frame_deadline_ms / 1e3
                # the detectors that take over from a stalled read keep grids away at once
                wary = partial(detector_for, s, wary=True)
                if s.detector_process == "always":
                    self._isolated = IsolatedDetector(
                        factory, deadline_s, stop=shared.stop, after_stall=wary
                    )
                else:
                    self._isolated = self.guard = GuardedDetector(
                        factory, deadline_s, stop=shared.stop, after_stall=wary
                    )
                detector = self._isolated
            self._pipeline = Pipeline(s, detector)
            if self._camera_info is not None:
                self._pipeline.use_camera_info(self._camera_info[0], *self._camera_info[1])
            if self._isolated is not None and start_detector:
                self._isolated.start()
            try:
                self._declare()
            except zenoh.ZError:
                self._release()
                raise
            self.opened = True

    def _declare(self) -> None:
        shared, s, name = self._shared, self._shared.settings, self.name
        # on an rmw_zenoh graph, the camera topic a pattern matched is listed as subscribed
        self._subscription = shared.ros.stream_subscription(self.key) if self.key else None
        self._tag_pub = shared.publishers.ros("tag", name, express=True)
        self._declared.append(self._tag_pub)
        self._record_pub = shared.publishers.record(stream_key(s.record_key, name))
        self._declared.append(self._record_pub)
        self._declared += self._ros_outputs.declare(_StreamPublishers(shared.publishers, name))
        if s.debug_image:
            self._debug_pub = shared.publishers.ros("debug_image", name, express=False)
            self._declared.append(self._debug_pub)
            self._listener = self._debug_pub.declare_matching_listener(self._on_debug_matching)

    def close(self) -> None:
        """Stop its detector's processes and undeclare its outputs (no worker holds it)."""
        if self._isolated is not None:
            self._isolated.close()
        self._release()

    def _release(self) -> None:
        entities: list[Any] = [self._listener] if self._listener is not None else []
        entities += [self._subscription] if self._subscription is not None else []
        self._listener = self._subscription = None
        for entity in entities:
            try:
                entity.undeclare()
            except zenoh.ZError as err:  # session already closed
                log.debug("event=undeclare_failed %s", kv(error=err))
        for publisher in reversed(self._declared):
            try:
                self._shared.publishers.release(publisher)
            except zenoh.ZError as err:
                log.debug("event=undeclare_failed %s", kv(error=err))
        self._declared.clear()

    @property
    def tag_key(self) -> str:
        return self._tag_pub.key if self._tag_pub is not None else ""

    @property
    def intrinsics(self) -> Intrinsics | None:
        return None if self._pipeline is None else self._pipeline.intrinsics

    @property
    def vetoed(self) -> dict[str, int]:
        return {} if self._pipeline is None else dict(self._pipeline.vetoed)

    # -- callbacks ----------------------------------------------------------------------------

    def use_camera_info(self, info: CameraInfo) -> bool:
        """Apply a CameraInfo's intrinsics to this stream's frames of its size; False when
        they are those in use already."""
        if info == self._camera_info:
            return False
        self._camera_info = info
        pipeline = self._pipeline
        if pipeline is not None:
            pipeline.use_camera_info(info[0], *info[1])
        return True

    def _on_debug_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            self.debug_watched.set()
        else:
            self.debug_watched.clear()
        self._log_limited(logging.INFO, "debug_image", "debug_image", watched=status.matching)

    # -- one frame ------------------------------------------------------------------------------

    def handle(self, arrival: Arrival) -> None:
        """Answer one frame, counting whatever goes wrong (see the module documentation).

        Raises:
            StaleDetection: the watchdog abandoned this thread's read (the thread must end).
            zenoh.ZError: the outputs could not be declared (the stream's first frame).

        """
        if not self.opened:
            self.open()
        try:
            self._process(arrival)
        except FrameDecodeError as err:
            self.reject(err.reason, err)
        except FrameAbandonedError as err:
            # No tag and no record for it; the detector was restarted for the next frame.
            self.stats.on_abandoned(err.elapsed_ms)
            self.reject(err.reason, err)
        except ProcessingError as err:
            # Failed before the tag was published: the frame is rejected.
            self.stats.on_processing_error(err.stage)
            self.reject(err.reason, err)

    def _process(self, arrival: Arrival) -> None:
        """Decode, analyse and publish one frame.

        Raises:
            FrameDecodeError: the payload is refused (its ``reason`` is counted).
            ProcessingError: the frame could not be analysed or its tag encoded.

        """
        started = time.monotonic_ns()
        s = self._shared.settings
        pipeline, tag_pub, record_pub = self._pipeline, self._tag_pub, self._record_pub
        assert pipeline is not None and tag_pub is not None and record_pub is not None
        sample = arrival.sample
        # The size is known before the one copy out of Zenoh: an oversized frame costs nothing.
        check_payload_size(len(sample.payload), s.max_frame_bytes)
        payload = sample.payload.to_bytes()
        attachment = sample.attachment
        if arrival.compressed:
            # colour only for a watched debug image; the detector reads grey
            frame = decode_compressed_cdr(
                payload, max_pixels=s.max_frame_pixels, grey=not self.debug_watched.is_set()
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
            pending = pipeline.begin(frame)
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
            tag = bytes(self._shared.codec.encode(pending.selected))
        except _ENCODE_ERRORS as err:
            raise ProcessingError("encode_tag", err) from err
        self._publish(tag_pub, "tag", tag)
        published = time.monotonic_ns()
        # From here on the frame is answered: later failures are counted, not rejections.
        try:
            analysis = pending.finish()
        except _DETECT_ERRORS as err:
            self.processing_failed(ProcessingError("detect", err))
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
            stream=str(sample.key_expr),
            instance=self._shared.instance,
        )
        try:
            self._publish(record_pub, "record", record.to_msgpack())
        except _ENCODE_ERRORS as err:
            self.processing_failed(ProcessingError("encode_record", err))
        self._publish_ros_outputs(analysis, record.stamp_ns, frame.frame_id)
        self.stats.on_processed(
            latency_ms,
            frame_ms=decode_ms + analysis.convert_ms + analysis.detect_ms,
            detect_ms=analysis.detect_ms,
        )
        self._hint_if_tagless(bool(analysis.tags))
        if self.debug_watched.is_set():
            try:
                self._publish_debug(frame, analysis, record.stamp_ns)
            except ProcessingError as err:
                self.processing_failed(err)

    def _hint_if_tagless(self, tagged: bool) -> None:
        """Once ``no_tag_hint_s`` of frames all had no tag, say what to check (once, until a
        tag is seen again)."""
        now = time.monotonic()
        s = self._shared.settings
        if tagged or s.no_tag_hint_s <= 0:
            self._tagless_since = None
            return
        if self._tagless_since is None:
            self._tagless_since = now
        elif now - self._tagless_since >= s.no_tag_hint_s:
            self._tagless_since = math.inf  # said: quiet until a tag is seen again
            log.info(
                "event=no_tag_hint %s",
                kv(
                    **self._named(),
                    seconds=s.no_tag_hint_s,
                    dictionary=s.dictionary,
                    detail="no tag in any frame: if tags are in view, run `zenoh-perception "
                    "probe` on a recording of this camera to find their dictionary",
                ),
            )

    def _publish_ros_outputs(self, analysis: Analysis, stamp_ns: int, frame_id: str) -> None:
        """Every detection and the tags' transforms (see service/ros_outputs.py)."""
        encoded, failed = self._ros_outputs.encode(analysis, stamp_ns=stamp_ns, frame_id=frame_id)
        for err in failed:
            self.processing_failed(err)
        for output in encoded:
            self._publish(output.publisher, output.name, output.payload)

    def _publish_debug(self, frame: Frame, analysis: Analysis, stamp_ns: int) -> None:
        """Annotate, encode and publish the debug image (at most ``debug_image_max_hz``).

        Raises:
            ProcessingError: drawing or encoding failed (stage ``debug_image``).

        """
        now = time.monotonic()
        s = self._shared.settings
        if self._debug_pub is None or now - self._last_debug < 1.0 / s.debug_image_max_hz:
            return
        self._last_debug = now
        try:
            image = annotate(
                to_bgr(frame),
                analysis.tags,
                analysis.selected,
                intrinsics=self.intrinsics,
                tag_size=s.tag_size_for,
            )
            payload = bytes(
                encode_compressed_image(
                    image,
                    quality=s.debug_jpeg_quality,
                    stamp_ns=stamp_ns,
                    frame_id=frame.frame_id,
                )
            )
        except _DEBUG_ERRORS as err:
            raise ProcessingError("debug_image", err) from err
        if self._publish(self._debug_pub, "debug_image", payload):
            self.debug_images += 1

    def _publish(self, publisher: TopicPublisher, output: str, payload: bytes) -> bool:
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

    # -- counting and logging -----------------------------------------------------------------

    def processing_failed(self, err: ProcessingError) -> None:
        self.stats.on_processing_error(err.stage)
        self._log_limited(
            logging.WARNING,
            f"processing:{err.stage}",
            "processing_error",
            stage=err.stage,
            detail=err,
        )

    def reject(self, reason: str, err: Exception) -> None:
        self.stats.on_rejected(reason)
        suppressed = self._shared.gate.admit(reason)
        if suppressed is not None:
            fields = kv(**self._named(), reason=reason, suppressed=suppressed, detail=err)
            log.warning("event=rejected %s", fields)

    def _log_limited(self, level: int, key: str, event: str, **fields: object) -> None:
        suppressed = self._shared.gate.admit(key)
        if suppressed is not None:
            log.log(
                level, "event=%s %s", event, kv(**self._named(), **fields, suppressed=suppressed)
            )

    def _named(self) -> dict[str, str]:
        """The fields naming the stream in its log lines, its name as the README gives it and
        its key (none with a single stream)."""
        return {"name": self.name, "stream": self.key} if self._shared.named else {}

    # -- observability ----------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """This stream's part of the status reply."""
        snapshot = self.stats.snapshot().as_dict()
        intrinsics = self.intrinsics
        snapshot["camera_info"]["intrinsics"] = None if intrinsics is None else asdict(intrinsics)
        return {
            "stream": self.key,
            "name": self.name,
            "tag_key": self.tag_key,
            "idle_s": round((time.monotonic_ns() - self.last_ns) / 1e9, 3),
            **snapshot,
            "vetoed_by_reason": self.vetoed,
            "debug_image": {"watched": self.debug_watched.is_set(), "published": self.debug_images},
        }
