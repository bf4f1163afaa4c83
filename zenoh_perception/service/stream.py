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

Zenoh's callback hands it a frame (:meth:`Stream.arrive`); its newest frame waits in its
:class:`~zenoh_perception.service.mailbox.Lane`, and one worker at a time answers it
(:meth:`Stream.handle`). :meth:`Stream.answer` is a frame's whole path, top to bottom:
decode (the input's decoder, bound when it was subscribed: the payload's size checked, one
copy out of Zenoh, a zero-copy view), detect up to the selected tag, publish ``tag``, finish
the frame (the veto's other detections, the look after the tag), then the record, the ROS
outputs and the debug image while it is watched (:class:`~zenoh_perception.service.outputs.
StreamOutputs`). Nothing outside the stream writes its state: the service reads its status,
and the watchdog asks it to check its deadline (:meth:`Stream.check_deadline`).

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
from dataclasses import asdict, dataclass
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
from zenoh_perception.pipeline import Analysis, Pending, Pipeline, detector_for
from zenoh_perception.service.child_detector import IsolatedDetector
from zenoh_perception.service.guard import GuardedDetector
from zenoh_perception.service.inputs import Decoder, StreamNaming
from zenoh_perception.service.logs import LimitedLog, kv
from zenoh_perception.service.mailbox import Lane, Scheduler
from zenoh_perception.service.outputs import PublisherPool, StreamOutputs
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.settings import DetectorProcess, Settings
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.wire.frames import Frame, check_payload_size
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.records import FrameRecord, TagCodec

log = logging.getLogger(__name__)

# What each stage may raise on a frame it cannot handle (OpenCV, rosbags' CDR serialiser,
# msgpack); anything else is a bug that stops the worker and makes ``run`` exit 1.
_DETECT_ERRORS: Final = (cv2.error, ValueError)
_ENCODE_ERRORS: Final = (struct.error, ValueError, OverflowError, TypeError)

#: Intrinsics of a CameraInfo and the image size they are for.
CameraInfo = tuple[Intrinsics, tuple[int, int]]


@dataclass(frozen=True, slots=True)
class Arrival:
    """A frame as Zenoh's callback left it: the sample, untouched, when it came, and the
    decoder of the input it came on."""

    sample: zenoh.Sample
    received_ns: int  # monotonic clock
    wall_ns: int  # time since the epoch
    decode: Decoder


@dataclass(frozen=True, slots=True)
class Shared:
    """What the service gives every stream."""

    settings: Settings
    session: zenoh.Session
    ros: RosTransport
    publishers: PublisherPool
    scheduler: Scheduler[Stream, Arrival]
    codec: TagCodec
    gate: LogGate
    totals: ServiceStats  # the service's counters: each stream's are counted there too
    instance: str  # the service's Zenoh id, in every record
    stop: threading.Event
    naming: StreamNaming
    #: A detector for every stream (tests): unguarded, shared.
    detector: Detector | None = None


@dataclass(frozen=True, slots=True)
class Stall:
    """A read the stream's deadline abandoned: the worker thread left inside it."""

    worker: int | None


@dataclass(frozen=True, slots=True)
class _Times:
    """When a frame's steps ended (monotonic ns)."""

    started: int
    decoded: int
    published: int


class Stream:
    """One camera's frames and everything the service keeps for them; see the module doc.

    Built in Zenoh's callback thread (cheap: counters and a lane); :meth:`open` (the first
    worker to take its frame, or the service at start for a stream known then) builds the
    pipeline and declares the outputs.
    """

    def __init__(self, name: str, shared: Shared) -> None:
        s = shared.settings
        #: The stream's name: what ``{stream}`` becomes in its output keys.
        self.name = name
        #: The concrete key its frames come on (the first frame's).
        self.input_key = ""
        self._shared = shared
        self.stats = ServiceStats(
            frame_budget_ms=s.limits.frame_budget_ms,
            frame_deadline_ms=s.limits.frame_deadline_ms or None,
            parent=shared.totals,
        )
        self.lane: Lane[Stream, Arrival] = shared.scheduler.lane(self)
        self.last_ns = time.monotonic_ns()  # the last frame's arrival
        self.opened = False
        self._worker: int | None = None  # the thread answering its frame (threading.get_ident)
        self.guard: GuardedDetector | None = None
        self._isolated: IsolatedDetector | GuardedDetector | None = None
        self._pipeline: Pipeline | None = None
        self._camera_info: CameraInfo | None = None
        self._subscription: Any = None  # a liveliness token, on an rmw_zenoh graph
        self._log = LimitedLog(log, shared.gate, self._named)
        self._outputs = StreamOutputs(
            shared.publishers, s, name, self._publish_failed, self._debug_watched
        )
        self._seq = 0
        # the frame in hand, once its tag is published (a read abandoned now lost its record):
        # what counting it as processed needs
        self._answered: tuple[Arrival, _Times] | None = None
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
            if detector is None and s.limits.frame_deadline_ms > 0:
                factory = partial(detector_for, s.detection)
                deadline_s = s.limits.frame_deadline_ms / 1e3
                # the detectors that take over from a stalled read keep grids away at once
                wary = partial(detector_for, s.detection, wary=True)
                threads = (
                    s.detection.opencv_threads
                )  # the child processes' own, set when each starts
                if s.limits.detector_process is DetectorProcess.ALWAYS:
                    self._isolated = IsolatedDetector(
                        factory,
                        deadline_s,
                        stop=shared.stop,
                        after_stall=wary,
                        opencv_threads=threads,
                    )
                else:
                    self._isolated = self.guard = GuardedDetector(
                        factory,
                        deadline_s,
                        stop=shared.stop,
                        after_stall=wary,
                        opencv_threads=threads,
                    )
                detector = self._isolated
            self._pipeline = Pipeline(s.detection, s.selection, detector)
            if self._camera_info is not None:
                self._pipeline.use_camera_info(self._camera_info[0], *self._camera_info[1])
            if self._isolated is not None and start_detector:
                self._isolated.start()
            try:
                # on an rmw_zenoh graph, the camera topic a pattern matched is listed as
                # subscribed
                key = self.input_key
                self._subscription = shared.ros.stream_subscription(key) if key else None
                self._outputs.declare()
            except zenoh.ZError:
                self._release()
                raise
            self.opened = True

    def close(self) -> None:
        """Stop its detector's processes and undeclare its outputs (no worker holds it)."""
        if self._isolated is not None:
            self._isolated.close()
        self._release()

    def _release(self) -> None:
        subscription, self._subscription = self._subscription, None
        if subscription is not None:
            try:
                subscription.undeclare()
            except zenoh.ZError as err:  # session already closed
                log.debug("event=undeclare_failed %s", kv(error=err))
        self._outputs.release()

    @property
    def tag_key(self) -> str:
        return self._outputs.tag_key

    @property
    def intrinsics(self) -> Intrinsics | None:
        return None if self._pipeline is None else self._pipeline.intrinsics

    @property
    def vetoed(self) -> dict[str, int]:
        return {} if self._pipeline is None else dict(self._pipeline.vetoed)

    @property
    def coarse_read(self) -> dict[str, int] | None:
        """The coarse first read's counters (None: not read coarsely, see
        :func:`~zenoh_perception.pipeline.coarse_read_for`)."""
        coarse = None if self._pipeline is None else self._pipeline.coarse
        return None if coarse is None else dict(coarse.counters)

    @property
    def debug_watched(self) -> threading.Event:
        return self._outputs.debug_watched

    @property
    def debug_images(self) -> int:
        return self._outputs.debug_images

    # -- callbacks ----------------------------------------------------------------------------

    def arrive(self, arrival: Arrival) -> None:
        """A frame came (Zenoh's callback thread: O(1), no copy): it waits in the lane,
        replacing a frame not yet taken (counted as dropped)."""
        self.last_ns = arrival.received_ns
        if not self.input_key:
            self.input_key = str(arrival.sample.key_expr)
        scheduler = self._shared.scheduler
        self.stats.on_received(scheduler.put(self.lane, arrival, arrival.received_ns))

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

    def _debug_watched(self, watched: bool) -> None:
        self._log(logging.INFO, "debug_image", "debug_image", watched=watched)

    # -- one frame ------------------------------------------------------------------------------

    def handle(self, arrival: Arrival) -> None:
        """Answer one frame in the calling worker, counting whatever goes wrong (see the
        module documentation).

        Raises:
            StaleDetection: the watchdog abandoned this thread's read (the thread must end).
            zenoh.ZError: the outputs could not be declared (the stream's first frame).

        """
        self._worker = threading.get_ident()
        if not self.opened:
            self.open()
        try:
            self.answer(arrival)
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

    def answer(self, arrival: Arrival) -> None:
        """A frame's whole path: decode, detect up to the selected tag, publish ``tag``, finish
        the frame, then the record and the outputs beside it.

        Raises:
            FrameDecodeError: the payload is refused (its ``reason`` is counted).
            ProcessingError: the frame could not be analysed or its tag encoded.

        """
        started = time.monotonic_ns()
        self._answered = None
        frame, kind = self._decode(arrival)
        decoded = time.monotonic_ns()
        pending = self._detect(frame)
        self._outputs.put_tag(self._encode_tag(pending))
        times = _Times(started, decoded, time.monotonic_ns())
        self._answered = (arrival, times)
        # From here on the frame is answered: later failures are counted, not rejections.
        analysis = self._finish(pending, arrival, times)
        if analysis is None:
            return
        record = self._record(arrival, frame, kind, analysis, times)
        self._put_record(record)
        self._outputs.put_ros(analysis, record.stamp_ns, frame.frame_id, self.processing_failed)
        self._count(arrival, analysis, times)
        self._hint_if_tagless(bool(analysis.tags))
        if self._outputs.debug_watched.is_set():
            self._put_debug(frame, analysis, record.stamp_ns)

    def _decode(self, arrival: Arrival) -> tuple[Frame, InputKind]:
        """The frame's pixels (a view of the one copy out of Zenoh) and how they were read.

        Raises:
            FrameDecodeError: the payload is refused.

        """
        s = self._shared.settings
        sample = arrival.sample
        # The size is known before the one copy out of Zenoh: an oversized frame costs nothing.
        check_payload_size(len(sample.payload), s.limits.max_frame_bytes)
        # colour only for a watched debug image; the detector reads grey
        grey = not self._outputs.debug_watched.is_set()
        return arrival.decode(
            sample.payload.to_bytes(), sample.attachment, s.limits.max_frame_pixels, grey
        )

    def _detect(self, frame: Frame) -> Pending:
        """The frame's selected tag, the rest of its analysis pending.

        Raises:
            ProcessingError: the detector failed on the frame (stage ``detect``).

        """
        assert self._pipeline is not None
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
            self._log(
                logging.WARNING,
                "intrinsics_mismatch",
                "intrinsics_mismatch",
                frame=f"{frame.width}x{frame.height}",
                detail="the CameraInfo in use is for another image size: its intrinsics are "
                "left out for this frame",
            )
        return pending

    def _encode_tag(self, pending: Pending) -> bytes:
        try:
            return bytes(self._shared.codec.encode(pending.selected))
        except _ENCODE_ERRORS as err:
            raise ProcessingError("encode_tag", err) from err

    def _finish(self, pending: Pending, arrival: Arrival, times: _Times) -> Analysis | None:
        """Every detection judged (None: the detector failed; the frame, answered, counted as
        processed and its lost record as the error)."""
        try:
            return pending.finish()
        except _DETECT_ERRORS as err:
            self._count_answered(arrival, times)  # first: the error never shows without it
            self.processing_failed(ProcessingError("detect", err))
            return None

    def _record(
        self,
        arrival: Arrival,
        frame: Frame,
        kind: InputKind,
        analysis: Analysis,
        times: _Times,
    ) -> FrameRecord:
        self._seq += 1
        return FrameRecord(
            stamp_ns=frame.stamp_ns if frame.stamp_ns is not None else arrival.wall_ns,
            frame_id=frame.frame_id,
            seq=frame.seq if frame.seq is not None else self._seq,
            width=frame.width,
            height=frame.height,
            selected=analysis.selected,
            tags=analysis.tags,
            timing_ms={
                "latency_ms": (times.published - arrival.received_ns) / 1e6,
                "queue_ms": (times.started - arrival.received_ns) / 1e6,
                "decode_ms": (times.decoded - times.started) / 1e6,
                "convert_ms": analysis.convert_ms,
                "detect_ms": analysis.detect_ms,
            },
            source=kind,
            input_key=str(arrival.sample.key_expr),
            instance=self._shared.instance,
            whole_selected=analysis.whole_selected,
        )

    def _put_record(self, record: FrameRecord) -> None:
        try:
            self._outputs.put_record(record)
        except ProcessingError as err:
            self.processing_failed(err)

    def _put_debug(self, frame: Frame, analysis: Analysis, stamp_ns: int) -> None:
        try:
            self._outputs.put_debug(frame, analysis, stamp_ns, self.intrinsics)
        except ProcessingError as err:
            self.processing_failed(err)

    def _count(self, arrival: Arrival, analysis: Analysis, times: _Times) -> None:
        decode_ms = (times.decoded - times.started) / 1e6
        self.stats.on_processed(
            (times.published - arrival.received_ns) / 1e6,
            frame_ms=decode_ms + analysis.convert_ms + analysis.detect_ms,
            detect_ms=analysis.detect_ms,
        )

    def _count_answered(self, arrival: Arrival, times: _Times) -> None:
        """A frame whose tag was published and whose analysis then failed: processed (so
        that ``received = processed + dropped + rejected`` holds), timed up to its tag."""
        self.stats.on_processed(
            (times.published - arrival.received_ns) / 1e6,
            frame_ms=(times.published - times.started) / 1e6,
            detect_ms=(times.published - times.decoded) / 1e6,
        )

    def _hint_if_tagless(self, tagged: bool) -> None:
        """Once ``no_tag_hint_s`` of frames all had no tag, say what to check (once, until a
        tag is seen again)."""
        now = time.monotonic()
        s = self._shared.settings
        if tagged or s.logs.no_tag_hint_s <= 0:
            self._tagless_since = None
            return
        if self._tagless_since is None:
            self._tagless_since = now
        elif now - self._tagless_since >= s.logs.no_tag_hint_s:
            self._tagless_since = math.inf  # said: quiet until a tag is seen again
            log.info(
                "event=no_tag_hint %s",
                kv(
                    **self._named(),
                    seconds=s.logs.no_tag_hint_s,
                    dictionary=s.detection.dictionary,
                    detail="no tag in any frame: if tags are in view, run `zenoh-perception "
                    "probe` on a recording of this camera to find their dictionary",
                ),
            )

    # -- the deadline ---------------------------------------------------------------------------

    def check_deadline(self) -> Stall | None:
        """Abandon the guarded read in flight when it has run past the deadline (counted: a
        rejection, or a processing error when the frame's tag was out already); the worker
        left inside it, or None."""
        guard = self.guard
        assert guard is not None
        elapsed_ms = guard.check()
        if elapsed_ms is None:
            return None
        err = FrameAbandonedError(elapsed_ms, guard.deadline_s * 1e3)
        self.stats.on_abandoned(elapsed_ms)
        answered = self._answered
        if answered is None:
            self.reject(err.reason, err)
            return Stall(self._worker)
        # the frame's tag was out: answered (processed), its record lost; the read abandoned
        # was the second look after the tag, or the whole read after a coarse read's tag
        stage = "second_look" if guard.abandoned_answered else "whole_read"
        self._count_answered(*answered)  # first: the error never shows without it
        self.processing_failed(ProcessingError(stage, err))
        return Stall(self._worker)

    # -- counting and logging -----------------------------------------------------------------

    def _publish_failed(self, output: str, err: zenoh.ZError) -> None:
        self.stats.on_publish_error(output)
        self._log(
            logging.WARNING,
            f"publish:{output}",
            "publish_failed",
            output=output,
            error=zenoh_error_text(err),
        )

    def processing_failed(self, err: ProcessingError) -> None:
        self.stats.on_processing_error(err.stage)
        self._log(
            logging.WARNING,
            f"processing:{err.stage}",
            "processing_error",
            stage=err.stage,
            detail=err,
        )

    def reject(self, reason: str, err: Exception) -> None:
        self.stats.on_rejected(reason)
        self._log(logging.WARNING, reason, "rejected", reason=reason, detail=err)

    def _named(self) -> dict[str, str]:
        """The fields naming the stream in its log lines, its name as the README gives it and
        its input key (none with a single stream)."""
        fields = self._shared.naming.fields(self.input_key)
        return {"name": self.name, **fields} if fields else {}

    # -- observability ----------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """This stream's part of the status reply."""
        snapshot = self.stats.snapshot().as_dict()
        intrinsics = self.intrinsics
        snapshot["camera_info"]["intrinsics"] = None if intrinsics is None else asdict(intrinsics)
        return {
            "stream": self.input_key,
            "name": self.name,
            "tag_key": self.tag_key,
            "idle_s": round((time.monotonic_ns() - self.last_ns) / 1e9, 3),
            **snapshot,
            "vetoed_by_reason": self.vetoed,
            "coarse_read": self.coarse_read,
            "debug_image": {
                "watched": self._outputs.debug_watched.is_set(),
                "published": self._outputs.debug_images,
            },
        }
