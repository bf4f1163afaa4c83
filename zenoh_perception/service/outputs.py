"""What a stream publishes: ``tag``, the record, the ROS outputs beside them and the debug
image while it is watched (:class:`StreamOutputs`), through the publishers the service's
streams share by key (:class:`PublisherPool`).

A failed put is counted by output and logged (rate-limited) by the stream that owns the
outputs (the ``failed`` callback); the stream carries on.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable
from typing import Any, Final

import cv2
import zenoh

from zenoh_perception.errors import ProcessingError
from zenoh_perception.pipeline import Analysis
from zenoh_perception.service.logs import kv
from zenoh_perception.service.ros_outputs import RosOutputs
from zenoh_perception.service.ros_transport import RosTransport, TopicPublisher
from zenoh_perception.settings import Settings
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.wire.debug_image import annotate, encode_compressed_image
from zenoh_perception.wire.frames import Frame, to_bgr
from zenoh_perception.wire.records import FrameRecord
from zenoh_perception.wire.stream_keys import output_key

log = logging.getLogger(__name__)

MSGPACK_ENCODING = zenoh.Encoding("application/msgpack")

_ENCODE_ERRORS: Final = (struct.error, ValueError, OverflowError, TypeError)
_DEBUG_ERRORS: Final = (cv2.error, struct.error, ValueError, OverflowError)


class PublisherPool:
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


class _StreamPublishers:
    """A stream's view of :class:`PublisherPool`, for :class:`RosOutputs`."""

    def __init__(self, pool: PublisherPool, stream: str) -> None:
        self._pool = pool
        self._stream = stream

    def publisher(self, role: str, *, express: bool = False) -> TopicPublisher:
        return self._pool.ros(role, self._stream, express=express)


class StreamOutputs:
    """One stream's publishers (declared by :meth:`declare`, undeclared by :meth:`release`)
    and how each of its outputs is put.

    ``failed(output, err)`` counts and logs a put Zenoh refused; ``debug_watched`` follows
    whether anyone subscribes the debug image (the only output not encoded for nobody).
    """

    def __init__(
        self,
        pool: PublisherPool,
        settings: Settings,
        stream: str,
        failed: Callable[[str, zenoh.ZError], None],
        watched: Callable[[bool], None],
    ) -> None:
        self._pool = pool
        self._settings = settings
        self._stream = stream
        self._failed = failed
        self._watched = watched
        self._ros = RosOutputs(settings.outputs, settings.detection.dictionary)
        self._declared: list[TopicPublisher] = []
        self._tag: TopicPublisher | None = None
        self._record: TopicPublisher | None = None
        self._debug: TopicPublisher | None = None
        self._listener: Any = None
        self.debug_watched = threading.Event()
        self._last_debug = 0.0
        self.debug_images = 0

    @property
    def tag_key(self) -> str:
        return self._tag.key if self._tag is not None else ""

    def declare(self) -> None:
        """Declare the stream's publishers.

        Raises:
            zenoh.ZError: Zenoh refused a declaration (those declared are the caller's to
                :meth:`release`).

        """
        pool, s, name = self._pool, self._settings, self._stream
        self._tag = pool.ros("tag", name, express=True)
        self._declared.append(self._tag)
        self._record = pool.record(output_key(s.outputs.record_key, name))
        self._declared.append(self._record)
        self._declared += self._ros.declare(_StreamPublishers(pool, name))
        if s.debug.debug_image:
            self._debug = pool.ros("debug_image", name, express=False)
            self._declared.append(self._debug)
            self._listener = self._debug.declare_matching_listener(self._on_debug_matching)

    def release(self) -> None:
        """Undeclare what :meth:`declare` declared (a failure is logged: the session closed)."""
        listener, self._listener = self._listener, None
        if listener is not None:
            try:
                listener.undeclare()
            except zenoh.ZError as err:
                log.debug("event=undeclare_failed %s", kv(error=err))
        for publisher in reversed(self._declared):
            try:
                self._pool.release(publisher)
            except zenoh.ZError as err:
                log.debug("event=undeclare_failed %s", kv(error=err))
        self._declared.clear()

    def _on_debug_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            self.debug_watched.set()
        else:
            self.debug_watched.clear()
        self._watched(status.matching)

    # -- a frame's outputs ------------------------------------------------------------------

    def put_tag(self, payload: bytes) -> None:
        assert self._tag is not None
        self._put(self._tag, "tag", payload)

    def put_record(self, record: FrameRecord) -> None:
        """Encode and put the record.

        Raises:
            ProcessingError: the record could not be encoded (stage ``encode_record``).

        """
        assert self._record is not None
        try:
            self._put(self._record, "record", record.to_msgpack())
        except _ENCODE_ERRORS as err:
            raise ProcessingError("encode_record", err) from err

    def put_ros(
        self,
        analysis: Analysis,
        stamp_ns: int,
        frame_id: str,
        failed: Callable[[ProcessingError], None],
    ) -> None:
        """Every detection and the tags' transforms (see service/ros_outputs.py); an output
        that fails to encode goes to ``failed`` before any is put."""
        encoded, errors = self._ros.encode(analysis, stamp_ns=stamp_ns, frame_id=frame_id)
        for err in errors:
            failed(err)
        for output in encoded:
            self._put(output.publisher, output.name, output.payload)

    def put_debug(
        self, frame: Frame, analysis: Analysis, stamp_ns: int, intrinsics: Intrinsics | None
    ) -> None:
        """Annotate, encode and put the debug image (at most ``debug_image_max_hz``).

        Raises:
            ProcessingError: drawing or encoding failed (stage ``debug_image``).

        """
        now = time.monotonic()
        s = self._settings
        if self._debug is None or now - self._last_debug < 1.0 / s.debug.debug_image_max_hz:
            return
        self._last_debug = now
        try:
            image = annotate(
                to_bgr(frame),
                analysis.tags,
                analysis.selected,
                intrinsics=intrinsics,
                tag_size=s.selection.tag_size_for,
            )
            payload = bytes(
                encode_compressed_image(
                    image,
                    quality=s.debug.debug_jpeg_quality,
                    stamp_ns=stamp_ns,
                    frame_id=frame.frame_id,
                )
            )
        except _DEBUG_ERRORS as err:
            raise ProcessingError("debug_image", err) from err
        if self._put(self._debug, "debug_image", payload):
            self.debug_images += 1

    def _put(self, publisher: TopicPublisher, output: str, payload: bytes) -> bool:
        """Put ``payload``; a failure goes to ``failed``."""
        try:
            publisher.put(payload)
        except zenoh.ZError as err:
            self._failed(output, err)
            return False
        return True
