"""The perception service: subscribes camera frames on Zenoh and publishes, per frame, the
closest ArUco tag and a record of every detection.

Subscribed (each key a setting; wildcards or a list of keys give a stream per camera):

- ``input_key`` (``zed/left/image``): raw frames (pixels + msgpack attachment) or
  sensor_msgs/Image CDR; ``compressed_input_key`` (``zed/left/image/compressed``):
  sensor_msgs/CompressedImage CDR;
- ``camera_info_key`` (off): sensor_msgs/CameraInfo CDR, the intrinsics of the poses.

Published, on every frame (``{stream}`` in a key: the stream's name):

- ``tag_key`` (``tag``): StarterProjectTag CDR (tag_id, x_tag_center_pixel,
  y_tag_center_pixel, closeness_metric), id -1 when no tag; first, before the rest;
- ``record_key`` (``perception/tags``): msgpack record of every detection, timings, source;
- ``detections_key`` (``perception/detections``): apriltag_msgs/AprilTagDetectionArray CDR,
  and ``tf_key`` (``tf``): tf2_msgs/TFMessage CDR, each only while someone subscribes;
- ``debug_image_key``: the annotated frame as sensor_msgs/CompressedImage CDR, with
  ``debug_image`` on and while someone subscribes.

Served: ``status_key`` (``perception/status``), a JSON status queryable; the liveliness
token ``<liveliness_key>/<zid>`` (``perception/alive``). With ``ros_transport = "rmw_zenoh"``
the topics are an rmw_zenoh node's (``ros_namespace``, ``ros_node_name``, ``ros_domain_id``).

Settings (config/perception.toml documents each; every one has a flag): detection
(``detector``, ``dictionary``, ``second_look``, ``verify``, ``confirm_frames``,
``min_tag_side_px``, ``policy``, ``metric``, ``tag_size_m``, the camera intrinsics); limits
(``max_frame_bytes``, ``max_frame_pixels``, ``frame_deadline_ms``, ``detector_process``,
``max_streams``, ``stream_idle_s``, ``workers``); logging (``log_interval_s``,
``stats_interval_s``, ``no_tag_hint_s``); sharing cameras (``share_group``).

Each camera is a stream (:mod:`~zenoh_perception.service.stream`, whose ``Stream.answer``
is a frame's whole path): a concrete ``input_key`` is one, declared at start; a wildcard one
(``cams/*/image``), or a list of keys (each subscribed apart), is a stream per concrete key it
matches, made when its first frame comes (at most ``max_streams``; further keys' frames are
refused and counted) and forgotten after ``stream_idle_s`` without a frame
(:mod:`~zenoh_perception.service.registry`; :class:`~zenoh_perception.service.inputs.
StreamNaming` decides). By default the service subscribes its input keys itself; built with
``subscribe_inputs=False`` it subscribes only the concrete keys it is told to
:meth:`PerceptionService.hold` (instances sharing cameras each hold theirs, or a share group,
:mod:`~zenoh_perception.service.group`, tells it which).

Threads:

- Zenoh's callback threads only stamp the arrival time and leave the sample in its stream's
  newest-frame lane (O(1), no copy, no decoding).
- ``workers`` worker threads (default one per core; OpenCV releases the GIL) each take the
  stream whose newest frame has waited longest and answer that frame
  (:mod:`~zenoh_perception.service.workers`); with ``frame_deadline_ms`` a watchdog thread
  abandons a detection past the deadline (:mod:`~zenoh_perception.service.watchdog`).
- One reporter thread writes the periodic stats line (and one per stream with a wildcard
  input; :mod:`~zenoh_perception.service.report`), and forgets idle streams.

Every repeating log line goes through one rate limit (``log_interval_s``) per event and
reason. Opening the session, and its limits, are :mod:`~zenoh_perception.service.session`'s.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import threading
import time
from collections.abc import Mapping
from functools import partial
from typing import Any, Final

import zenoh

from zenoh_perception.detect.opencv import set_opencv_threads
from zenoh_perception.detect.types import Detector
from zenoh_perception.errors import ProcessingError, SessionError, zenoh_error_text
from zenoh_perception.service import report
from zenoh_perception.service.group import StreamGroup, camera_sources, settings_fingerprint
from zenoh_perception.service.inputs import (
    CDR,
    COMPRESSED,
    DECODERS,
    RAW,
    Decoder,
    StreamNaming,
    kind_of,
)
from zenoh_perception.service.liveliness import OtherServices
from zenoh_perception.service.logs import LimitedLog, kv
from zenoh_perception.service.mailbox import Scheduler
from zenoh_perception.service.outputs import MSGPACK_ENCODING, PublisherPool
from zenoh_perception.service.registry import StreamRegistry
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.service.session import (
    CONNECT_WARNING_S,
    check_transport_limit,
    close_within,
    connect_endpoints,
    open_session,
    session_endpoints,
    warn_if_unlinked,
)
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.service.stream import Arrival, Shared, Stream
from zenoh_perception.service.threads import guarded_thread
from zenoh_perception.service.watchdog import watch
from zenoh_perception.service.workers import Workers, usable_cpus
from zenoh_perception.settings import DetectorProcess, Settings
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.records import TagCodec
from zenoh_perception.wire.ros_topics import input_role

log = logging.getLogger(__name__)

__all__ = ["MSGPACK_ENCODING", "PROCESSING_ERROR", "PerceptionService", "run"]

#: Rejection reason of a decoded frame the pipeline failed on (a detector bug, counted).
PROCESSING_ERROR = ProcessingError.reason
#: Rejection reason of a frame of a new stream while ``max_streams`` streams are served.
TOO_MANY_STREAMS: Final = "too_many_streams"
#: Seconds close() waits, in all, for the service's threads to end.
_JOIN_S: Final = 1.0
#: Period at which idle streams are looked for, seconds (at most).
_REAP_S: Final = 1.0


class PerceptionService:
    """Subscribes frames and publishes tags, a stream per camera; see the module doc.

    Two ways to say which cameras it serves:

    - ``subscribe_inputs=True`` (the default, ``run``): it subscribes ``input_key`` and
      ``compressed_input_key`` itself (through the ROS transport; each key of a list apart),
      and every concrete key their wildcards or lists match is a stream.
    - ``subscribe_inputs=False``: it subscribes no frames until told; :meth:`hold` subscribes
      one concrete camera key (a stream) and :meth:`release` unsubscribes it and forgets its
      stream. Everything else (outputs per stream, CameraInfo, status, liveliness) is as in
      the default mode.

    ``detector`` (tests) serves every stream, unguarded; by default each stream builds the
    settings' detector.
    """

    def __init__(
        self,
        session: zenoh.Session,
        settings: Settings,
        *,
        detector: Detector | None = None,
        subscribe_inputs: bool = True,
        endpoints: Mapping[str, str] | None = None,  # what event=started says of the session
    ) -> None:
        self.settings = settings
        self._endpoints = dict(endpoints or {})
        #: The service's totals: every stream's counts, and the frames refused before any.
        self.stats = ServiceStats(
            frame_budget_ms=settings.limits.frame_budget_ms,
            frame_deadline_ms=settings.limits.frame_deadline_ms or None,
        )
        self._session = session
        self._ros = RosTransport(session, settings.ros, settings.topic_keys())
        # Callbacks read the zid from here: asking the session while it closes raises.
        self._zid = str(session.zid())
        self._subscribe_inputs = subscribe_inputs
        self._stop = threading.Event()
        self._gate = LogGate(settings.logs.log_interval_s)
        self._log = LimitedLog(log, self._gate)
        self._others = OtherServices(
            settings.outputs, settings.group, self._gate, zid=self._zid, stop=self._stop
        )
        self._scheduler: Scheduler[Stream, Arrival] = Scheduler()
        #: What each stream is named, and whether lines name it.
        self.naming = StreamNaming(settings.inputs, self._ros)
        self._shared = Shared(
            settings=settings,
            session=session,
            ros=self._ros,
            publishers=PublisherPool(session, self._ros),
            scheduler=self._scheduler,
            codec=TagCodec(settings.ros.ros_package),
            gate=self._gate,
            totals=self.stats,
            instance=self._zid,
            stop=self._stop,
            naming=self.naming,
            detector=detector,
        )
        self._streams = StreamRegistry(self._shared)
        # per held key: its subscription
        self._held: dict[str, Any] = {}
        self._held_lock = threading.Lock()
        #: Set when a worker thread died unexpectedly (the service then answers nothing).
        self.failed = threading.Event()
        self._workers = Workers(self._scheduler, self._stop, self.failed, pulse=self._pulse)
        self._declared: list[Any] = []
        self._group: StreamGroup | None = None  # with share_group: the streams held
        self._threads: list[threading.Thread] = []
        self._started = False

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> None:
        """Declare subscribers, the status queryable and the liveliness token (and, with a
        concrete input, the stream's publishers).

        Raises:
            SessionError: Zenoh refused a declaration (e.g. the session is closed).

        """
        if self._started:
            return
        self._started = True
        # process-wide: set once, before any stream reads a frame
        set_opencv_threads(self.settings.detection.opencv_threads)
        try:
            self._declare()
        except zenoh.ZError as err:
            msg = f"cannot declare the service's keys: {zenoh_error_text(err)}"
            raise SessionError(msg) from err
        report.log_started(
            self.settings,
            self._ros,
            zid=self._session.zid(),
            named=self.naming.named,
            workers=self._worker_count(),
            endpoints=self._endpoints,
        )

    def _declare(self) -> None:
        s, session = self.settings, self._session
        node_token = self._ros.declare_node()
        if node_token is not None:
            self._declared.append(node_token)
        # the streams known before any frame: their outputs declared and their detectors'
        # child processes ready before the first frame
        self._streams.open_at_start()
        if s.inputs.camera_info_key:
            self._declared.extend(
                self._ros.subscribe("camera_info", self._streams.camera_infos.on_sample)
            )
        self._declared.append(
            session.declare_queryable(s.outputs.status_key, self._on_status_query)
        )
        token_key = f"{s.outputs.liveliness_key}/{session.zid()}"
        self._declared.append(session.liveliness().declare_token(token_key))
        # another service under the same liveliness key, there now or later, is reported:
        # two services on the same keys publish every tag twice
        self._declared.append(
            session.liveliness().declare_subscriber(
                f"{s.outputs.liveliness_key}/*", self._others.on_token, history=True
            )
        )
        self._threads = [guarded_thread(self._report, name="perception-stats", failed=self.failed)]
        if (
            s.limits.frame_deadline_ms > 0
            and s.limits.detector_process is not DetectorProcess.ALWAYS
        ):
            loop = partial(watch, self._streams.guarded, self._workers, self._scheduler, self._stop)
            self._threads.append(
                guarded_thread(loop, name="perception-watchdog", failed=self.failed)
            )
        for thread in self._threads:
            thread.start()
        for _ in range(self._worker_count()):
            self._workers.start_one()
        if s.group.share_group:
            # only the announced streams the group gives this instance, each on its key
            self._group = StreamGroup(
                session,
                name=s.group.share_group,
                liveliness_key=s.outputs.liveliness_key,
                sources=camera_sources(s.inputs, s.ros),
                fingerprint=settings_fingerprint(s),
                capacity=s.inputs.max_streams,
                take=self.hold,
                release=self.release,
                gate=self._gate,
                failed=self.failed,
            )
            self._group.start()
            return
        if not self._subscribe_inputs:
            return
        # Subscribe last: every frame that arrives finds the workers ready.
        # a subscription per key of each input (Zenoh has no union of key expressions)
        if self._ros.rmw_zenoh:
            # raw frames (msgpack attachment) keep coming on the plain keys
            for key in s.inputs.input_entries:
                self._declared.append(session.declare_subscriber(key, self._receiver(RAW)))
            if s.inputs.input_key:
                self._declared.extend(self._ros.subscribe(input_role(CDR), self._receiver(CDR)))
        elif s.inputs.input_key:
            self._declared.extend(self._ros.subscribe(input_role(RAW), self._receiver(RAW)))
        if s.inputs.compressed_input_key:
            self._declared.extend(
                self._ros.subscribe(input_role(COMPRESSED), self._receiver(COMPRESSED))
            )

    def _worker_count(self) -> int:
        if self.settings.limits.workers > 0:
            return self.settings.limits.workers
        several = self.naming.most_streams > 1 or not self._subscribe_inputs
        return len(usable_cpus()) if several else 1

    def close(self) -> None:
        """Stop the workers, undeclare everything (the session itself is the caller's)."""
        if self._group is not None:  # its streams first: the others take them once it is gone
            self._group.close()
        self._stop.set()
        self._scheduler.close()
        with self._held_lock:
            held, self._held = list(self._held.values()), {}
        streams = self._streams.all()
        # A worker inside OpenCV is not waited for, nor one abandoned before: each ends on
        # its own (daemon threads).
        stuck = {s.guard.abandon() for s in streams if s.guard is not None}
        workers = self._workers.running(stuck)
        # One deadline for them all: a worker still busy then (a frame's last OpenCV calls)
        # is left too; the process then ends without finalizing under it (signals.leave).
        deadline = time.monotonic() + _JOIN_S
        for thread in [*self._threads, *workers]:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
        for entity in [*reversed(self._declared), *held]:
            try:
                entity.undeclare()
            except zenoh.ZError as err:  # session already closed
                log.debug("event=undeclare_failed %s", kv(error=err))
        for stream in streams:
            stream.close()
        self._declared.clear()
        log.info("event=stopped %s", kv(**self.stats.snapshot().as_dict()["frames"]))

    def __enter__(self) -> PerceptionService:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- the cameras served -------------------------------------------------------------------

    def hold(self, input_key: str) -> None:
        """Subscribe the frames of the concrete key ``input_key`` (its stream is made when
        its first frame comes). Idempotent; thread-safe; meant for ``subscribe_inputs=False``.

        ``input_key`` is a key ``input_key`` matches (raw frames or sensor_msgs/Image CDR;
        with ``ros_transport = "rmw_zenoh"`` the topic's rmw_zenoh key) or one
        ``compressed_input_key`` matches (CompressedImage CDR).

        Raises:
            SettingsError: ``input_key`` is not a concrete key either input matches.
            SessionError: Zenoh refused the subscription.

        """
        kind = self._kind_of(input_key)
        with self._held_lock:
            if input_key in self._held or self._stop.is_set():
                return
            try:
                # called on Zenoh's own thread (O(1)): no thread of its own per held stream
                self._held[input_key] = self._session.declare_subscriber(
                    input_key,
                    zenoh.handlers.Callback(self._receiver(kind), indirect=False),
                )
            except zenoh.ZError as err:
                msg = f"cannot subscribe {input_key!r}: {zenoh_error_text(err)}"
                raise SessionError(msg) from err

    def release(self, input_key: str) -> None:
        """Unsubscribe ``input_key`` and forget its stream (its detector state, counters and
        publishers; a frame being answered is answered first). Idempotent; thread-safe."""
        with self._held_lock:
            subscriber = self._held.pop(input_key, None)
            if subscriber is None:
                return
            others = [self._name_of(k) for k in self._held]
        try:
            subscriber.undeclare()
        except zenoh.ZError as err:  # session closed
            log.debug("event=undeclare_failed %s", kv(error=err))
        name = self._name_of(input_key)
        if name is not None and name not in others:
            self._streams.retire(name)

    def held(self) -> list[str]:
        """The keys :meth:`hold` subscribed, sorted."""
        with self._held_lock:
            return sorted(self._held)

    def streams(self) -> list[str]:
        """The keys of the streams served now (the key each one's last frame came on)."""
        return [stream.input_key for stream in self._streams.by_key()]

    def _pulse(self) -> None:
        """The worker loop's heartbeat (a share group's proof that this instance works)."""
        group = self._group
        if group is not None:
            group.beat()

    def _kind_of(self, key: str) -> InputKind:
        """The input whose samples ``key`` carries (SettingsError: none, or not concrete)."""
        return kind_of(key, self.settings.inputs, self._ros)

    def _name_of(self, key: str) -> str | None:
        """The name of the stream the concrete ``key`` belongs to; None when it matches no
        input."""
        return self.naming.name(self._kind_of(key), key)

    # -- Zenoh callbacks: O(1), never block ---------------------------------------------------

    def _receiver(self, kind: InputKind) -> partial[None]:
        """The callback of a subscription to input ``kind``: its decoder bound here."""
        return partial(self._on_input, kind, DECODERS[kind])

    def _on_input(self, kind: InputKind, decode: Decoder, sample: zenoh.Sample) -> None:
        arrival = Arrival(sample, time.monotonic_ns(), time.time_ns(), decode)
        name = self.naming.name(kind, str(sample.key_expr))
        stream = None if name is None else self._streams.serve(name)
        if stream is None:
            if self._stop.is_set():
                return
            self.stats.on_received(False)
            self.stats.on_rejected(TOO_MANY_STREAMS)
            self._log(
                logging.WARNING,
                TOO_MANY_STREAMS,
                "rejected",
                reason=TOO_MANY_STREAMS,
                key=str(sample.key_expr),
                max_streams=self.settings.inputs.max_streams,
            )
            return
        stream.arrive(arrival)

    def _on_status_query(self, query: zenoh.Query) -> None:
        try:
            query.reply(
                self.settings.outputs.status_key,
                json.dumps(self.status()),
                encoding=zenoh.Encoding.APPLICATION_JSON,
            )
        except zenoh.ZError as err:  # the querier or the session went away
            self._log(
                logging.DEBUG, "status_reply", "status_reply_failed", error=zenoh_error_text(err)
            )

    # -- observability -----------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The JSON-ready status: the totals, each stream's, and the effective settings."""
        totals = self.stats.snapshot().as_dict()
        return report.status_document(
            totals,
            self._streams.by_key(),
            retired_vetoes=self._streams.retired_vetoes,
            named=self.naming.named,
            zid=self._zid,
            worker_alive=not self.failed.is_set(),
            other_services=self._others.count,
            group=None if self._group is None else self._group.status(),
            held=self.held(),
            settings=self.settings,
        )

    def _report(self) -> None:
        interval = self.settings.logs.stats_interval_s
        next_report = time.monotonic() + interval if interval > 0 else math.inf
        while not self._stop.wait(min(_REAP_S, max(0.0, next_report - time.monotonic()))):
            self._streams.reap()
            if time.monotonic() < next_report:
                continue
            next_report += interval
            report.log_stats(
                self.status(),
                per_stream=self.naming.named,
                input_key=",".join(self.settings.inputs.input_entries),
            )


def run(conf: zenoh.Config, settings: Settings, stop: threading.Event) -> int:
    """Serve until ``stop`` is set (exit code 0) or the worker dies (exit code 1).

    Raises:
        SettingsError: ``max_frame_bytes`` exceeds the Zenoh configuration's message limit.
        SessionError: the Zenoh session cannot be opened or the service's keys declared.

    """
    check_transport_limit(conf, settings.limits)
    session = open_session(conf, stop, log_interval_s=settings.logs.log_interval_s)
    if session is None:
        return 0
    endpoints, described = connect_endpoints(conf), session_endpoints(conf)
    try:
        with PerceptionService(session, settings, endpoints=described) as service:
            # What start-up made (modules, the OpenCV and Zenoh bindings, the pipeline) lives
            # as long as the process: out of the collector's way. A full collection that
            # scanned it would delay the frame in progress, at a high frame rate long enough
            # for the next frame to replace a waiting one (a drop).
            gc.freeze()
            check_at = time.monotonic() + CONNECT_WARNING_S if endpoints else math.inf
            while not stop.wait(0.5):
                if service.failed.is_set():
                    return 1
                if time.monotonic() >= check_at:
                    check_at = math.inf
                    warn_if_unlinked(session, endpoints)
        return 0
    finally:
        close_within(session)
