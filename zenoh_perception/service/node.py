"""The perception service: the thin layer that wires streams, transports and the pure
pipeline to Zenoh.

Each camera is a stream (:mod:`~zenoh_perception.service.stream`): a concrete ``input_key``
is one, declared at start; a wildcard one (``cams/*/image``) is a stream per concrete key it
matches, made when its first frame comes (at most ``max_streams``; further keys' frames are
refused and counted) and forgotten after ``stream_idle_s`` without a frame. By default the
service subscribes its input keys itself; built with ``subscribe_inputs=False`` it subscribes
only the concrete keys it is told to :meth:`PerceptionService.hold` (instances sharing
cameras each hold theirs).

Threads:

- Zenoh's callback threads only stamp the arrival time and leave the sample in its stream's
  newest-frame lane (O(1), no copy, no decoding).
- ``workers`` worker threads (default one per core; OpenCV releases the GIL) each take the
  stream whose newest frame has waited longest, one worker per stream at a time
  (:mod:`~zenoh_perception.service.mailbox`), and answer that frame
  (:meth:`~zenoh_perception.service.stream.Stream.handle`).
- With ``frame_deadline_ms`` a frame the detector does not finish in time is abandoned (a
  rejection, counted with its time) and the stream's newest frame read next by a fresh
  detector. By default (``detector_process = "on_stall"``) detection runs in the worker and
  a watchdog thread abandons a read past the deadline, leaves that worker to end on its own
  and starts another (:mod:`~zenoh_perception.service.guard`); for a while after, the
  stream's frames go to a child process that is killed on a stall
  (:mod:`~zenoh_perception.service.watchdog`), as every frame does with ``"always"``.
- One reporter thread writes the periodic stats line (and one per stream with a wildcard
  input), and forgets idle streams.

Every repeating log line goes through one rate limit (``log_interval_s``) per event and
reason.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import os
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import asdict
from functools import partial
from typing import Any, Final

import zenoh

from zenoh_perception import __version__
from zenoh_perception.detect.types import Detector
from zenoh_perception.errors import (
    CameraInfoError,
    FrameAbandonedError,
    IntrinsicsError,
    ProcessingError,
    SessionError,
    SettingsError,
    zenoh_error_text,
)
from zenoh_perception.pipeline import VETO_REASONS
from zenoh_perception.service.group import StreamGroup
from zenoh_perception.service.guard import StaleDetection
from zenoh_perception.service.logs import kv
from zenoh_perception.service.mailbox import Scheduler
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.service.stats import LogGate, ServiceStats
from zenoh_perception.service.stream import (
    MSGPACK_ENCODING,
    Arrival,
    CameraInfo,
    Publishers,
    Shared,
    Stream,
)
from zenoh_perception.settings import Settings
from zenoh_perception.wire.camera_info import check_camera_info_size, decode_camera_info
from zenoh_perception.wire.records import TagCodec
from zenoh_perception.wire.stream_keys import has_wildcard, stream_name

log = logging.getLogger("zenoh_perception.service.node")

__all__ = ["MSGPACK_ENCODING", "PROCESSING_ERROR", "PerceptionService", "run"]

#: Rejection reason of a decoded frame the pipeline failed on (a detector bug, counted).
PROCESSING_ERROR = ProcessingError.reason
#: Rejection reason of a frame of a new stream while ``max_streams`` streams are served.
TOO_MANY_STREAMS: Final = "too_many_streams"
#: Rejection reason of a frame whose stream's outputs Zenoh refused to declare.
STREAM_REFUSED: Final = "stream_refused"
_POLL_S = 0.1
#: Seconds close() waits, in all, for the service's threads to end.
_JOIN_S: Final = 1.0
#: Zenoh configuration path of the largest message a session accepts.
MAX_MESSAGE_SIZE_PATH: Final = "transport/link/rx/max_message_size"
#: Room a frame message needs besides its payload: the attachment (at most 4 KiB), the key
#: and Zenoh's own headers.
MESSAGE_OVERHEAD_BYTES: Final = 8192
#: Period at which idle streams are looked for, seconds (at most).
_REAP_S: Final = 1.0

#: The inputs, by role: (subscription role, sample flags).
_RAW, _ROS, _COMPRESSED = "raw", "ros", "compressed"


class PerceptionService:
    """Subscribes frames and publishes tags, a stream per camera; see the module doc.

    Two ways to say which cameras it serves:

    - ``subscribe_inputs=True`` (the default, ``run``): it subscribes ``input_key`` and
      ``compressed_input_key`` itself (through the ROS transport), and every concrete key
      their wildcards match is a stream.
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
    ) -> None:
        self.settings = settings
        #: The service's totals: every stream's counts, and the frames refused before any.
        self.stats = ServiceStats(
            frame_budget_ms=settings.frame_budget_ms,
            frame_deadline_ms=settings.frame_deadline_ms or None,
        )
        self._session = session
        self._ros = RosTransport(session, settings)
        # Callbacks read the zid from here: asking the session while it closes raises.
        self._zid = str(session.zid())
        self._subscribe_inputs = subscribe_inputs
        self._other_tokens = 0
        self._other_lock = threading.Lock()
        self._stop = threading.Event()
        self._gate = LogGate(settings.log_interval_s)
        self._scheduler: Scheduler[Stream, Arrival] = Scheduler()
        #: Several streams: a wildcard input (a concrete one is one stream, made at start).
        self.wildcard = has_wildcard(settings.input_key) or has_wildcard(
            settings.compressed_input_key
        )
        self._shared = Shared(
            settings=settings,
            session=session,
            ros=self._ros,
            publishers=Publishers(session, self._ros),
            scheduler=self._scheduler,
            codec=TagCodec(settings.ros_package),
            gate=self._gate,
            totals=self.stats,
            instance=self._zid,
            stop=self._stop,
            detector=detector,
            named=self.wildcard,
        )
        self._streams: dict[str, Stream] = {}
        self._streams_lock = threading.Lock()
        # CameraInfos by stream name ("" for every stream), for streams made later too
        self._camera_infos: OrderedDict[str, CameraInfo] = OrderedDict()
        self._retired_vetoes: Counter[str] = Counter(dict.fromkeys(VETO_REASONS, 0))
        # per held key: its subscription
        self._held: dict[str, Any] = {}
        self._held_lock = threading.Lock()
        # the key expression each input role's samples match, and its stream names' source
        self._patterns: dict[str, str] = {}
        #: Set when a worker thread died unexpectedly (the service then answers nothing).
        self.failed = threading.Event()
        self._declared: list[Any] = []
        self._group: StreamGroup | None = None  # with share_group: the streams held
        self._threads: list[threading.Thread] = []
        self._workers: list[threading.Thread] = []
        #: Workers whose read the watchdog abandoned (each ends on its own).
        self._abandoned: set[int | None] = set()
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
        try:
            self._declare()
        except zenoh.ZError as err:
            msg = f"cannot declare the service's keys: {zenoh_error_text(err)}"
            raise SessionError(msg) from err
        s = self.settings
        log.info(
            "event=started %s",
            kv(
                version=__version__,
                zid=self._session.zid(),
                ros_transport=s.ros_transport,
                input=self._ros.key("camera") if s.input_key else "",
                compressed_input=(
                    self._ros.key("compressed_camera") if s.compressed_input_key else ""
                ),
                tag=s.tag_key if self.wildcard else self._ros.key("tag"),
                record=s.record_key,
                detector=s.detector,
                dictionary=s.dictionary,
                policy=s.policy,
                metric=s.metric,
                max_frame_bytes=s.max_frame_bytes,
                max_frame_pixels=s.max_frame_pixels,
                workers=self._worker_count(),
                max_streams=s.max_streams if self.wildcard else 1,
            ),
        )

    def _declare(self) -> None:
        s, session = self.settings, self._session
        node_token = self._ros.declare_node()
        if node_token is not None:
            self._declared.append(node_token)
        if not self.wildcard:
            # one stream, there from the start: its outputs declared and its detector's
            # child processes ready before the first frame, as a single camera's service was
            stream = Stream("", self._shared)
            stream.open(start_detector=True)
            self._streams[""] = stream
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
        if s.frame_deadline_ms > 0 and s.detector_process != "always":
            self._threads.append(
                threading.Thread(target=self._watch, name="perception-watchdog", daemon=True)
            )
        for thread in self._threads:
            thread.start()
        for _ in range(self._worker_count()):
            self._start_worker()
        # the key expressions whose chunks name the streams
        if s.input_key:
            self._patterns[_RAW] = s.input_key
            self._patterns[_ROS] = s.input_key
        if s.compressed_input_key:
            self._patterns[_COMPRESSED] = s.compressed_input_key
        if s.share_group:
            # only the announced streams the group gives this instance, each on its key
            self._group = StreamGroup(
                session,
                name=s.share_group,
                liveliness_key=s.liveliness_key,
                patterns=[k for k in (s.input_key, s.compressed_input_key) if k],
                take=self.hold,
                release=self.release,
            )
            self._group.start()
            return
        if not self._subscribe_inputs:
            return
        # Subscribe last: every frame that arrives finds the workers ready.
        if self._ros.rmw_zenoh:
            # raw frames (msgpack attachment) keep coming on the plain key
            if s.input_key:
                self._declared.append(
                    session.declare_subscriber(s.input_key, partial(self._on_input, _RAW))
                )
            if s.input_key:
                self._declared.append(self._ros.subscribe("camera", partial(self._on_input, _ROS)))
        elif s.input_key:
            self._declared.append(self._ros.subscribe("camera", partial(self._on_input, _RAW)))
        if s.compressed_input_key:
            self._declared.append(
                self._ros.subscribe("compressed_camera", partial(self._on_input, _COMPRESSED))
            )

    def _worker_count(self) -> int:
        if self.settings.workers > 0:
            return self.settings.workers
        return len(_usable_cpus()) if self.wildcard or not self._subscribe_inputs else 1

    def close(self) -> None:
        """Stop the workers, undeclare everything (the session itself is the caller's)."""
        if self._group is not None:  # its streams first: the others take them once it is gone
            self._group.close()
        self._stop.set()
        self._scheduler.close()
        with self._held_lock:
            held, self._held = list(self._held.values()), {}
        with self._streams_lock:
            streams = list(self._streams.values())
        # A worker inside OpenCV is not waited for, nor one abandoned before: each ends on
        # its own (daemon threads).
        stuck = {s.guard.abandon() for s in streams if s.guard is not None} | self._abandoned
        current = [w for w in self._workers if w.is_alive()]
        # One deadline for them all: a worker still busy then (a frame's last OpenCV calls)
        # is left too; the process then ends without finalizing under it (signals.leave).
        deadline = time.monotonic() + _JOIN_S
        for thread in [*self._threads, *(w for w in current if w.ident not in stuck)]:
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

    def hold(self, stream_key: str) -> None:
        """Subscribe the frames of the concrete key ``stream_key`` (its stream is made when
        its first frame comes). Idempotent; thread-safe; meant for ``subscribe_inputs=False``.

        ``stream_key`` is a key ``input_key`` matches (raw frames or sensor_msgs/Image CDR;
        with ``ros_transport = "rmw_zenoh"`` the topic's rmw_zenoh key) or one
        ``compressed_input_key`` matches (CompressedImage CDR).

        Raises:
            SettingsError: ``stream_key`` is not a concrete key either input matches.
            SessionError: Zenoh refused the subscription.

        """
        role = self._role_of(stream_key)
        with self._held_lock:
            if stream_key in self._held or self._stop.is_set():
                return
            try:
                self._held[stream_key] = self._session.declare_subscriber(
                    stream_key, partial(self._on_input, role)
                )
            except zenoh.ZError as err:
                msg = f"cannot subscribe {stream_key!r}: {zenoh_error_text(err)}"
                raise SessionError(msg) from err

    def release(self, stream_key: str) -> None:
        """Unsubscribe ``stream_key`` and forget its stream (its detector state, counters and
        publishers; a frame being answered is answered first). Idempotent; thread-safe."""
        with self._held_lock:
            subscriber = self._held.pop(stream_key, None)
            if subscriber is None:
                return
            others = [self._name_of(self._role_of(k), k) for k in self._held]
        try:
            subscriber.undeclare()
        except zenoh.ZError as err:  # session closed
            log.debug("event=undeclare_failed %s", kv(error=err))
        name = self._name_of(self._role_of(stream_key), stream_key)
        if name is not None and name not in others:
            self._retire(name)

    def held(self) -> list[str]:
        """The keys :meth:`hold` subscribed, sorted."""
        with self._held_lock:
            return sorted(self._held)

    def streams(self) -> list[str]:
        """The keys of the streams served now (the key each one's last frame came on)."""
        with self._streams_lock:
            return sorted(s.key for s in self._streams.values())

    def _role_of(self, key: str) -> str:
        """The input whose samples ``key`` carries."""
        if "*" in key or "$" in key:
            msg = f"{key!r} is not a concrete key"
            raise SettingsError(msg)
        s, concrete = self.settings, zenoh.KeyExpr(key)
        if s.input_key:
            if self._ros.rmw_zenoh and zenoh.KeyExpr(self._ros.key("camera")).intersects(concrete):
                return _ROS
            if zenoh.KeyExpr(s.input_key).intersects(concrete):
                return _RAW
        compressed = self._ros.key("compressed_camera") if s.compressed_input_key else ""
        if compressed and zenoh.KeyExpr(compressed).intersects(concrete):
            return _COMPRESSED
        msg = f"{key!r} matches neither input_key nor compressed_input_key"
        raise SettingsError(msg)

    def _name_of(self, role: str, key: str) -> str | None:
        """The name of the stream ``key`` (a sample's key on input ``role``) belongs to;
        None when it matches no input."""
        if not self.wildcard:
            return ""
        topic = key if role == _RAW else self._ros.topic_of(key)
        return stream_name(self._patterns.get(role, ""), topic)

    def _stream(self, name: str) -> Stream | None:
        """The stream ``name``, made when new (None past ``max_streams``)."""
        stream = self._streams.get(name)
        if stream is not None:
            return stream
        with self._streams_lock:
            stream = self._streams.get(name)
            if stream is None and not self._stop.is_set():
                if len(self._streams) >= self.settings.max_streams:
                    return None
                stream = self._streams[name] = Stream(name, self._shared)
                info = self._camera_infos.get(name) or self._camera_infos.get("")
                if info is not None:
                    stream.use_camera_info(info)
            return stream

    def _retire(self, name: str) -> None:
        """Forget stream ``name``: its counters stay in the totals, its vetoes too."""
        with self._streams_lock:
            stream = self._streams.pop(name, None)
        if stream is None:
            return
        self._retired_vetoes.update(stream.vetoed)
        if self._scheduler.remove(stream.lane):
            stream.close()  # else the worker holding it closes it
        log.info("event=stream_forgotten %s", kv(stream=stream.key))

    # -- Zenoh callbacks: O(1), never block ---------------------------------------------------

    def _on_input(self, role: str, sample: zenoh.Sample) -> None:
        now = time.monotonic_ns()
        arrival = Arrival(
            sample, now, time.time_ns(), ros_cdr=role == _ROS, compressed=role == _COMPRESSED
        )
        name = "" if not self.wildcard else self._name_of(role, str(sample.key_expr))
        stream = None if name is None else self._stream(name)
        if stream is None:
            if self._stop.is_set():
                return
            self.stats.on_received(False)
            self.stats.on_rejected(TOO_MANY_STREAMS)
            suppressed = self._gate.admit(TOO_MANY_STREAMS)
            if suppressed is not None:
                log.warning(
                    "event=rejected %s",
                    kv(
                        reason=TOO_MANY_STREAMS,
                        key=str(sample.key_expr),
                        max_streams=self.settings.max_streams,
                        suppressed=suppressed,
                    ),
                )
            return
        stream.last_ns = now
        if not stream.key:
            stream.key = str(sample.key_expr)
        stream.stats.on_received(self._scheduler.put(stream.lane, arrival, now))

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
        camera: CameraInfo = (intrinsics, (info.width, info.height))
        # with a wildcard input, a CameraInfo is its stream's (named as the frames' keys
        # are); a concrete camera_info_key's is every stream's
        name = ""
        if self.wildcard:
            topic = self._ros.topic_of(str(sample.key_expr))
            name = stream_name(self.settings.camera_info_key, topic) or ""
        with self._streams_lock:
            self._camera_infos[name] = camera
            self._camera_infos.move_to_end(name)
            while len(self._camera_infos) > self.settings.max_streams:
                self._camera_infos.popitem(last=False)
            targets = [
                s for s in self._streams.values() if name in ("", s.name) or not self.wildcard
            ]
        changed = [stream.use_camera_info(camera) for stream in targets]
        if any(changed):
            # A camera whose intrinsics change on every message would flood the log: the
            # line is rate-limited and the status always shows the intrinsics in use.
            self._log_limited(
                logging.INFO,
                "intrinsics",
                "intrinsics",
                **({"stream": name} if self.wildcard else {}),
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

    # -- workers ------------------------------------------------------------------------------

    def _start_worker(self) -> None:
        worker = threading.Thread(target=self._work, name="perception-worker", daemon=True)
        # only the current workers and the abandoned ones still running are kept
        self._workers = [w for w in self._workers if w.is_alive()] + [worker]
        worker.start()

    def _work(self) -> None:
        replaced = False
        try:
            while not self._stop.is_set():
                taken = self._scheduler.take(_POLL_S)
                if taken is None:
                    continue
                lane, arrival = taken
                stream = lane.owner
                stream.worker = threading.get_ident()
                try:
                    stream.handle(arrival)
                except zenoh.ZError as err:  # the stream's outputs could not be declared
                    stream.reject(STREAM_REFUSED, SessionError(zenoh_error_text(err)))
                if self._scheduler.done(lane):
                    stream.close()  # forgotten while this worker answered its frame
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

    def _watch(self) -> None:
        """Abandon an in-process detection past the deadline, and start another worker."""
        wait = _POLL_S
        while not self._stop.wait(wait):
            with self._streams_lock:
                guarded = [s for s in self._streams.values() if s.guard is not None]
            wait = _POLL_S
            for stream in guarded:
                guard = stream.guard
                assert guard is not None
                elapsed_ms = guard.check()
                if elapsed_ms is None:
                    wait = min(wait, guard.poll_s())
                    continue
                err = FrameAbandonedError(elapsed_ms, guard.deadline_s * 1e3)
                stream.stats.on_abandoned(elapsed_ms)
                stream.reject(err.reason, err)
                self._abandoned.add(stream.worker)
                self._start_worker()
                # the stuck worker ends on its own: the stream is free for the next frame
                if self._scheduler.done(stream.lane):
                    stream.close()

    def _log_limited(self, level: int, key: str, event: str, **fields: object) -> None:
        """Log ``event`` at most once per ``log_interval_s`` for ``key``, saying how many
        lines were left out since the last one."""
        suppressed = self._gate.admit(key)
        if suppressed is not None:
            log.log(level, "event=%s %s", event, kv(**fields, suppressed=suppressed))

    # -- observability -----------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The JSON-ready status: the totals, each stream's, and the effective settings."""
        snapshot = self.stats.snapshot().as_dict()
        with self._streams_lock:
            streams = sorted(self._streams.values(), key=lambda s: s.key)
        per_stream = [stream.status() for stream in streams]
        vetoed = Counter(self._retired_vetoes)
        for stream in per_stream:
            vetoed.update(stream["vetoed_by_reason"])
        single = streams[0] if not self.wildcard and streams else None
        intrinsics = None if single is None else single.intrinsics
        snapshot["camera_info"]["intrinsics"] = None if intrinsics is None else asdict(intrinsics)
        return {
            "service": "zenoh-perception",
            "version": __version__,
            "zid": self._zid,
            "worker_alive": not self.failed.is_set(),
            **snapshot,
            "liveliness": {"other_services": self._other_tokens},
            "group": None if self._group is None else self._group.status(),
            "vetoed_by_reason": dict(vetoed),
            "debug_image": {
                "watched": any(s.debug_watched.is_set() for s in streams),
                "published": sum(s.debug_images for s in streams),
            },
            "streams": per_stream,
            "held": self.held(),
            "settings": self.settings.as_dict(),
        }

    def _report(self) -> None:
        interval = self.settings.stats_interval_s
        next_report = time.monotonic() + interval if interval > 0 else math.inf
        while not self._stop.wait(min(_REAP_S, max(0.0, next_report - time.monotonic()))):
            if self.wildcard:
                self._reap()
            if time.monotonic() < next_report:
                continue
            next_report += interval
            self._log_stats()

    def _reap(self) -> None:
        """Forget the streams idle for ``stream_idle_s``."""
        horizon = time.monotonic_ns() - int(self.settings.stream_idle_s * 1e9)
        with self._streams_lock:
            idle = [name for name, s in self._streams.items() if s.last_ns < horizon]
        for name in idle:
            self._retire(name)

    def _log_stats(self) -> None:
        status = self.status()
        frames = status["frames"]
        if frames["received"] == 0:
            # a line of zeros says nothing: say what is awaited, and where
            log.info(
                "event=waiting_for_frames %s",
                kv(key=self.settings.input_key, detail="no frame received yet"),
            )
            return
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
        if not self.wildcard:
            return
        for stream in status["streams"]:
            frames, latency = stream["frames"], stream["latency_ms"]
            log.info(
                "event=stream_stats %s",
                kv(
                    stream=stream["stream"],
                    received=frames["received"],
                    processed=frames["processed"],
                    dropped=frames["dropped"],
                    rejected=frames["rejected"],
                    fps=f"{stream['fps']:.1f}",
                    latency_p50_ms=f"{latency['p50']:.2f}",
                    latency_p99_ms=f"{latency['p99']:.2f}",
                    abandoned=stream["budget"]["abandoned"],
                ),
            )


def _usable_cpus() -> set[int]:
    """The CPUs this process may run on."""
    try:
        return os.sched_getaffinity(0)
    except AttributeError:  # not Linux
        return set(range(os.cpu_count() or 1))


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
