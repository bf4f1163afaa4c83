"""The pieces the stress tools and the tests share to drive a service: marker frames, a
raw-frame camera, a listener of the service's outputs, a wait on its status, /proc readings.

Status counts (:func:`~zenoh_perception_bench.processes.frames_of`,
:func:`~zenoh_perception_bench.processes.is_idle`) come from the package's bench, which uses
them too."""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, cast

import cv2
import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.service.status import query_status
from zenoh_perception.tags.selection import TagMessage
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.records import TagCodec, decode_record

Pixels = npt.NDArray[np.uint8]

INPUT_KEY: Final = "zed/left/image"
TAG_KEY: Final = "tag"
RECORD_KEY: Final = "perception/tags"
STATUS_KEY: Final = "perception/status"


# -- frames ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MarkerFrame:
    """A BGRA frame holding one ArUco marker whose centre is known exactly."""

    width: int
    height: int
    tag_id: int
    center: tuple[float, float]
    payload: bytes  # the BGRA pixels, row-major, no padding


def marker_frame(
    width: int,
    height: int,
    tag_id: int,
    *,
    side: int | None = None,
    origin: tuple[int, int] | None = None,
    clutter: bool = False,
    seed: int = 0,
    dictionary: int = cv2.aruco.DICT_4X4_50,
) -> MarkerFrame:
    """One marker of ``side`` px at ``origin`` (top-left, px) on white or on random clutter.

    ``clutter`` fills the background with random grey blocks: many contours for the detector
    to reject, so processing is slower (like a real, textured scene).
    """
    side = side if side is not None else max(60, min(width, height) // 4)
    quiet = max(4, side // 6)
    x0, y0 = origin if origin is not None else ((width - side) // 2, (height - side) // 2)
    if x0 < quiet or y0 < quiet or x0 + side + quiet > width or y0 + side + quiet > height:
        msg = f"a {side}px marker at {x0},{y0} does not fit a {width}x{height} frame"
        raise ValueError(msg)
    if clutter:
        rng = np.random.default_rng(seed)
        shape = ((height + 7) // 8, (width + 7) // 8)
        blocks = rng.integers(0, 256, shape, dtype=np.uint8).astype(np.uint8)
        tiled = np.repeat(np.repeat(blocks, 8, axis=0), 8, axis=1)[:height, :width]
        gray: Pixels = np.ascontiguousarray(tiled, dtype=np.uint8)
    else:
        gray = np.full((height, width), 255, dtype=np.uint8)
    gray[y0 - quiet : y0 + side + quiet, x0 - quiet : x0 + side + quiet] = 255
    marker = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(dictionary), tag_id, side
    )
    gray[y0 : y0 + side, x0 : x0 + side] = marker
    bgra = cast(Pixels, cv2.cvtColor(gray, cv2.COLOR_GRAY2BGRA))
    # Pixel centres are at integer coordinates: the marker spans [x0 - 0.5, x0 + side - 0.5].
    center = (x0 + side / 2 - 0.5, y0 + side / 2 - 0.5)
    return MarkerFrame(width, height, tag_id, center, bgra.tobytes())


def raw_attachment(
    width: int, height: int, *, seq: int | None = None, encoding: str = "bgra8"
) -> bytes:
    """The msgpack attachment of a raw frame (stamped now)."""
    return RawFrameMeta(width, height, encoding, stamp_ns=time.time_ns(), seq=seq).to_msgpack()


# -- Zenoh helpers -----------------------------------------------------------------------------


class Camera:
    """Publishes raw frames on ``key``.

    With ``block`` (the default) Zenoh blocks the publisher instead of dropping samples when
    its queue is full, so every frame reaches the service and the service alone decides what
    to drop.
    """

    def __init__(self, session: zenoh.Session, key: str = INPUT_KEY, *, block: bool = True) -> None:
        congestion = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
        self._publisher = session.declare_publisher(key, congestion_control=congestion)

    def wait_matched(self, timeout: float = 10.0) -> None:
        """Block until a subscriber (the service) matches; TimeoutError otherwise."""
        matched: queue.Queue[bool] = queue.Queue()
        listener = self._publisher.declare_matching_listener(
            lambda status: matched.put(status.matching)
        )
        try:
            deadline = time.monotonic() + timeout
            while (left := deadline - time.monotonic()) > 0:
                try:
                    if matched.get(timeout=left):
                        return
                except queue.Empty:
                    break
        finally:
            listener.undeclare()  # type: ignore[no-untyped-call]
        msg = f"no subscriber matched {self._publisher.key_expr} within {timeout} s"
        raise TimeoutError(msg)

    def put(self, frame: MarkerFrame, seq: int) -> None:
        self._publisher.put(
            frame.payload, attachment=raw_attachment(frame.width, frame.height, seq=seq)
        )

    def put_raw(self, payload: bytes, attachment: bytes | None) -> None:
        self._publisher.put(payload, attachment=attachment)

    def close(self) -> None:
        self._publisher.undeclare()  # type: ignore[no-untyped-call]


@dataclass(frozen=True, slots=True)
class Answer:
    """One output of the service, as a camera-side observer sees it."""

    kind: str  # "tag" or "record"
    received: float  # time.monotonic() at arrival
    tag: TagMessage | None = None
    record: dict[str, Any] | None = None


class Listener:
    """Queues every ``tag`` and ``perception/tags`` sample, decoded, in arrival order."""

    def __init__(
        self, session: zenoh.Session, *, tag_key: str = TAG_KEY, record_key: str = RECORD_KEY
    ) -> None:
        self.answers: queue.Queue[Answer] = queue.Queue()
        self.undecodable = 0
        self._codec = TagCodec()
        self._subscribers = [
            session.declare_subscriber(tag_key, self._on_tag),
            session.declare_subscriber(record_key, self._on_record),
        ]

    def _on_tag(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        try:
            tag = self._codec.decode(sample.payload.to_bytes())
        except MessageDecodeError:
            self.undecodable += 1
            return
        self.answers.put(Answer("tag", now, tag=tag))

    def _on_record(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        try:
            record = decode_record(sample.payload.to_bytes())
        except MessageDecodeError:
            self.undecodable += 1
            return
        self.answers.put(Answer("record", now, record=record))

    def get(self, timeout: float) -> Answer:
        """The next answer; queue.Empty after ``timeout`` s."""
        return self.answers.get(timeout=timeout)

    def drain(self) -> list[Answer]:
        items: list[Answer] = []
        while True:
            try:
                items.append(self.answers.get_nowait())
            except queue.Empty:
                return items

    def record_for(self, seq: int, timeout: float) -> tuple[dict[str, Any], list[Answer]]:
        """Wait for the record of frame ``seq``; also return every answer that came before."""
        before: list[Answer] = []
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                answer = self.answers.get(timeout=left)
            except queue.Empty:
                break
            if answer.record is not None and answer.record.get("seq") == seq:
                return answer.record, before
            before.append(answer)
        msg = f"no record for seq {seq} within {timeout} s"
        raise TimeoutError(msg)

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()  # type: ignore[no-untyped-call]


def wait_status(
    session: zenoh.Session,
    predicate: Callable[[dict[str, Any]], bool],
    *,
    key: str = STATUS_KEY,
    timeout: float = 30.0,
    what: str = "condition",
) -> dict[str, Any]:
    """Poll the status queryable until ``predicate(status)``; TimeoutError otherwise."""
    deadline = time.monotonic() + timeout
    last: dict[str, Any] | None = None
    while time.monotonic() < deadline:
        replies = query_status(session, key, timeout=1.0, gather=False)
        if replies:
            last = replies[0]
            if predicate(last):
                return last
        time.sleep(0.02)
    msg = f"status never met {what} within {timeout} s (last: {last and last['frames']})"
    raise TimeoutError(msg)


# -- /proc readings (Linux) ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ProcSample:
    """Resident memory, threads and open file descriptors of one process."""

    rss_kib: int
    threads: int
    fds: int


def proc_sample(pid: int | None = None) -> ProcSample:
    """Read /proc/<pid>/status and /proc/<pid>/fd (``pid`` None: this process)."""
    base = Path("/proc") / ("self" if pid is None else str(pid))
    rss = threads = 0
    for line in (base / "status").read_text(encoding="ascii").splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1])
        elif line.startswith("Threads:"):
            threads = int(line.split()[1])
    return ProcSample(rss, threads, sum(1 for _ in (base / "fd").iterdir()))


def percentile(values: Sequence[float], pct: float) -> float:
    """Linear-interpolated percentile; 0.0 for no values."""
    if not values:
        return 0.0
    return float(np.percentile(np.asarray(values, dtype=np.float64), pct))
