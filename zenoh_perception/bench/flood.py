"""Camera flood: frames far faster than the service processes them, then one marked frame.

``python -m zenoh_perception.bench.flood --resolution HD720 --ratio 8 --count 240`` starts the
service in this process (loopback peers, no multicast), measures its processing time, floods
frames at ``ratio`` times its processing rate and then checks what a rover needs:

- memory stays bounded (RSS after the flood versus after a warm-up burst);
- no backlog: at the end of the flood at most two frames wait (the one in progress and the
  newest), and a marked frame (its own tag id and seq) sent then is answered after at most the
  one in progress. To make that count exact, the worker is held inside one frame
  (:class:`HoldableDetector`) for the flood's last quarter;
- every frame is accounted for: ``received == processed + dropped + rejected`` with
  ``dropped > 0``.

The building blocks (marker frames, a raw-frame camera, a listener of the service's outputs,
/proc readings, status counts) are shared with the soak and fuzz scripts, the benches and the
tests.
"""

from __future__ import annotations

import argparse
import json
import queue
import statistics
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Final, cast

import cv2
import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.service.status import query_status
from zenoh_perception.settings import Settings
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


def frames_of(status: dict[str, Any]) -> dict[str, int]:
    frames: dict[str, int] = status["frames"]
    return frames


def is_idle(status: dict[str, Any]) -> bool:
    """Every received frame was processed, dropped or rejected (nothing left in the mailbox)."""
    f = frames_of(status)
    return f["received"] == f["processed"] + f["dropped"] + f["rejected"]


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
    msg = f"status never met {what} within {timeout} s (last: {last and frames_of(last)})"
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


# -- the load check ------------------------------------------------------------------------------


class HoldableDetector:
    """Wraps a detector; after :meth:`hold` the next ``detect`` waits until :meth:`release`.

    The load check holds the service's worker inside one frame while the flood's tail and the
    marked frame arrive, so "how many frames are answered before the marked one" does not
    depend on thread timing.
    """

    def __init__(self, inner: Detector, *, max_hold_s: float = 60.0) -> None:
        self._inner = inner
        self._max_hold_s = max_hold_s
        self._released = threading.Event()
        self._released.set()
        self.holding = threading.Event()

    def hold(self) -> None:
        self.holding.clear()
        self._released.clear()

    def release(self) -> None:
        self._released.set()

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        if not self._released.is_set():
            self.holding.set()
            self._released.wait(self._max_hold_s)
        return self._inner.detect(gray)


@dataclass(frozen=True, slots=True)
class LoadConfig:
    resolution: str = "HD720"
    ratio: float = 8.0  # flood rate / processing rate
    count: int = 240  # flood frames
    warmup: int = 5  # frames sent one at a time to measure the processing time
    max_rate_hz: float = 2000.0
    flood_tag: int = 3
    marked_tag: int = 9
    timeout_s: float = 60.0


@dataclass(slots=True)
class LoadReport:
    resolution: str
    frame_bytes: int
    processing_ms: float  # median service latency of warm-up frames sent one at a time
    target_rate_hz: float
    flood_frames: int
    flood_s: float
    rss_before_kib: int  # after a warm-up burst
    rss_after_kib: int  # at the end of the flood (worker held, marked frame waiting)
    dropped_before_hold: int  # dropped during the flood while the worker ran freely
    waiting_after_flood: int  # frames received but not yet handled, at the end of the flood
    stale_frames: int  # frames processed after the flood, before the marked one (counters)
    stale_records: int  # records answered after the flood, before the marked one's
    marked_tag_id: int
    expected_tag_id: int
    marked_center: tuple[float, float]
    expected_center: tuple[float, float]
    status: dict[str, Any] = field(default_factory=dict)

    @property
    def achieved_rate_hz(self) -> float:
        return self.flood_frames / self.flood_s if self.flood_s > 0 else 0.0

    @property
    def rss_growth_kib(self) -> int:
        return self.rss_after_kib - self.rss_before_kib

    def problems(self, max_growth_frames: float = 16.0) -> list[str]:
        """What is wrong (empty: the service coped): memory, backlog, accounting, answer."""
        out: list[str] = []
        bound_kib = max_growth_frames * self.frame_bytes / 1024
        if self.rss_growth_kib > bound_kib:
            out.append(
                f"RSS grew {self.rss_growth_kib} KiB over the flood (> {bound_kib:.0f} KiB, "
                f"{max_growth_frames:g} frames)"
            )
        if self.waiting_after_flood > 2:
            out.append(f"backlog: {self.waiting_after_flood} frames waiting after the flood")
        if self.stale_frames > 1 or self.stale_records > 1:
            out.append(
                f"backlog: {self.stale_frames} stale frames ({self.stale_records} records) "
                "answered before the marked frame"
            )
        if self.marked_tag_id != self.expected_tag_id:
            out.append(f"marked frame answered tag {self.marked_tag_id}")
        f = frames_of(self.status)
        if self.dropped_before_hold <= 0:
            out.append("no frame dropped: the flood did not outrun the service")
        if not is_idle(self.status):
            out.append(f"frames unaccounted for: {f}")
        return out

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["achieved_rate_hz"] = round(self.achieved_rate_hz, 1)
        data["rss_growth_kib"] = self.rss_growth_kib
        return data


def _pace(start: float, index: int, rate_hz: float) -> None:
    delay = start + index / rate_hz - time.monotonic()
    if delay > 0:
        time.sleep(delay)


def _waiting(status: dict[str, Any]) -> int:
    f = frames_of(status)
    return f["received"] - f["processed"] - f["dropped"] - f["rejected"]


def run_load(
    session: zenoh.Session,
    gate: HoldableDetector,
    config: LoadConfig = LoadConfig(),
    *,
    rss_kib: Callable[[], int] = lambda: proc_sample().rss_kib,
) -> LoadReport:
    """Flood the service reachable through ``session`` (whose detector is ``gate``).

    1. Frames one at a time give the processing time; a warm-up burst brings Zenoh's buffers
       and the allocator to their working size; RSS is read.
    2. ``count`` frames at ``ratio`` times the processing rate. For the last quarter the worker
       is held inside one frame; then a marked frame (its own tag id and seq) is sent and RSS
       read again: every frame is in, and at most two may wait (the held one and the newest).
    3. Released, the service must answer the marked frame after at most the held one.

    ``rss_kib`` reads the memory to watch (default: this process, where an in-process service
    lives). The service must be idle and use the default keys.
    """
    width, height = RESOLUTIONS[config.resolution]
    # Four backgrounds in turn: a moving scene, which a tracking detector cannot shortcut.
    floods = [
        marker_frame(width, height, config.flood_tag, clutter=True, seed=seed)
        for seed in range(10, 14)
    ]
    side = max(60, min(width, height) // 4)
    marked = marker_frame(
        width, height, config.marked_tag, clutter=True, seed=2, origin=(side // 2, side // 2)
    )
    camera = Camera(session)
    listener = Listener(session)
    gate.release()
    try:
        camera.wait_matched()
        wait_status(session, lambda s: True, timeout=config.timeout_s, what="an answer")
        processing: list[float] = []
        seq = 1_000_000
        for i in range(config.warmup):
            seq += 1
            camera.put(floods[i % len(floods)], seq)
            record, _before = listener.record_for(seq, config.timeout_s)
            processing.append(float(record["timing"]["latency_ms"]))  # idle: no queueing
        processing_ms = statistics.median(processing)
        rate = min(config.max_rate_hz, config.ratio * 1000.0 / max(processing_ms, 0.1))
        sent = config.warmup

        dropped_before_hold: list[int] = []

        def flood_burst(count: int, first_seq: int, hold_at: int | None = None) -> float:
            start = time.monotonic()
            for i in range(count):
                if i == hold_at:
                    replies = query_status(session, STATUS_KEY, timeout=1.0, gather=False)
                    dropped_before_hold.append(frames_of(replies[0])["dropped"] if replies else 0)
                    gate.hold()
                _pace(start, i, rate)
                camera.put(floods[i % len(floods)], first_seq + i)
            return time.monotonic() - start

        def settle(total: int) -> dict[str, Any]:
            return wait_status(
                session,
                lambda s: frames_of(s)["received"] >= total and is_idle(s),
                timeout=config.timeout_s,
                what=f"{total} frames received and handled",
            )

        burst = max(10, config.count // 4)
        flood_burst(burst, 2_000_000)
        sent += burst
        dropped_after_warmup = frames_of(settle(sent))["dropped"]
        rss_before = rss_kib()

        flood_s = flood_burst(config.count, 0, hold_at=config.count * 3 // 4)
        sent += config.count
        if not gate.holding.wait(config.timeout_s):
            msg = "the service's worker never reached the held detector"
            raise TimeoutError(msg)
        marked_seq = 3_000_000
        camera.put(marked, marked_seq)
        sent += 1
        held = wait_status(
            session,
            lambda s: frames_of(s)["received"] >= sent,
            timeout=config.timeout_s,
            what=f"{sent} frames received",
        )
        rss_after = rss_kib()
        listener.drain()
        gate.release()

        record, before = listener.record_for(marked_seq, config.timeout_s)
        final = settle(sent)
        selected = record["selected"]
        return LoadReport(
            resolution=config.resolution,
            frame_bytes=len(floods[0].payload),
            processing_ms=processing_ms,
            target_rate_hz=rate,
            flood_frames=config.count,
            flood_s=flood_s,
            rss_before_kib=rss_before,
            rss_after_kib=rss_after,
            dropped_before_hold=dropped_before_hold[0] - dropped_after_warmup,
            waiting_after_flood=_waiting(held),
            stale_frames=frames_of(final)["processed"] - frames_of(held)["processed"] - 1,
            stale_records=sum(1 for a in before if a.record is not None),
            marked_tag_id=int(selected["tag_id"]),
            expected_tag_id=config.marked_tag,
            marked_center=(
                float(selected["x_tag_center_pixel"]),
                float(selected["y_tag_center_pixel"]),
            ),
            expected_center=marked.center,
            status=final,
        )
    finally:
        gate.release()
        listener.close()
        camera.close()


# -- command line ---------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m zenoh_perception.bench.flood", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--resolution", choices=sorted(RESOLUTIONS), default="HD720")
    parser.add_argument("--ratio", type=float, default=8.0, help="flood rate / processing rate")
    parser.add_argument("--count", type=int, default=240, help="frames in the flood")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    args = parser.parse_args(argv)
    config = LoadConfig(resolution=args.resolution, ratio=args.ratio, count=args.count)
    endpoint = loopback_endpoint()
    settings = Settings(stats_interval_s=0.0)
    gate = HoldableDetector(make_detector(settings.detector, settings.dictionary))
    with (
        zenoh.open(loopback_config(listen=[endpoint])) as service_session,
        PerceptionService(service_session, settings, detector=gate),
        zenoh.open(loopback_config(connect=[endpoint])) as camera_session,
    ):
        report = run_load(camera_session, gate, config)
    problems = report.problems()
    if args.json:
        print(json.dumps({**report.as_dict(), "problems": problems}, indent=2))
    else:
        f = frames_of(report.status)
        print(
            f"{report.resolution}: processing {report.processing_ms:.1f} ms/frame, flood "
            f"{report.flood_frames} frames at {report.achieved_rate_hz:.0f} Hz "
            f"({report.achieved_rate_hz * report.processing_ms / 1000:.1f}x processing)\n"
            f"RSS {report.rss_before_kib / 1024:.1f} -> {report.rss_after_kib / 1024:.1f} MiB; "
            f"frames {f} ({report.dropped_before_hold} dropped before the hold); after the "
            f"flood {report.waiting_after_flood} frame(s) waiting, "
            f"{report.stale_frames} stale frame(s) answered before the marked one"
        )
        for problem in problems:
            print(f"PROBLEM: {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
