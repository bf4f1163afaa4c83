"""Services in processes of their own, and the bench's side of them (camera and consumer).

Each service is the deployed CLI (``zenoh-perception run --detector NAME``, or the transport
floor, :mod:`zenoh_perception_bench.floor`) in its own process, on keys of its own, ``-l`` a
loopback port, multicast scouting off. The bench process is only the camera and the consumer:
one Zenoh peer that the services dial (the bench listens first, so no connect-retry timer
delays a start). A service is ready once its frame subscriber matches the bench's publisher
(it declares it last) and a warm-up frame has been answered; no fixed sleeps.

By default the camera puts each frame from a Zenoh shared-memory buffer
(:class:`~zenoh_perception.camera.shm.ShmPutter`), as a camera on the service's machine does:
the frame is written into its buffer before the clock starts (a camera writes its image into
its buffer anyway; the write time is reported as ``write_median_ms``). Without shared memory
it puts plain ``bytes``, which Zenoh copies inside the timed interval.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from typing import Any, Final, TextIO

import msgpack
import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.camera.shm import Loaded, ShmPutter
from zenoh_perception.errors import PerceptionError
from zenoh_perception.service.status import query_status
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception_bench._loopback import loopback_endpoint
from zenoh_perception_bench.runners import DICTIONARY
from zenoh_perception_bench.scene import Scene
from zenoh_perception_bench.scoring import rounded

Image = npt.NDArray[np.uint8]

#: The services measured end to end (``zenoh-perception run --detector NAME``).
E2E_DETECTORS: Final = ("opencv", "tracking")
#: The transport floor's name among them (:mod:`zenoh_perception_bench.floor`).
FLOOR: Final = "floor"
#: The floor reading each frame with OpenCV's default in its callback (``floor --detect``).
OPENCV_PEER: Final = "opencv-peer"
#: seq of the warm-up frames (never a measured frame's).
WARMUP_SEQ: Final = 10**9
#: A service process must answer within this (its start-up imports OpenCV and Zenoh, which can
#: take many seconds on a loaded machine).
STARTUP_TIMEOUT_S: Final = 90.0
ANSWER_TIMEOUT_S: Final = 30.0


def start_service(
    endpoint: str, log: TextIO, *extra: str, module: Sequence[str] = ("zenoh_perception", "run")
) -> subprocess.Popen[bytes]:
    """The real CLI listening on ``endpoint`` (loopback, no multicast scouting); ``module``:
    what ``python -m`` runs instead (the bench's transport floor)."""
    command = [
        sys.executable,
        "-m",
        *module,
        "-l",
        endpoint,
        "--no-multicast-scouting",
        *extra,
    ]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)


def stop_service(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> tuple[int, float]:
    """SIGTERM; (exit code, seconds to exit). Killed (code -9) if it does not exit in time."""
    started = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    return code, time.monotonic() - started


@contextmanager
def sigterm_exits() -> Iterator[None]:
    """SIGTERM raises SystemExit meanwhile, so the ``finally`` blocks stop the service
    processes (Python's default SIGTERM would end the bench and leave them running)."""

    def exit_now(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, exit_now)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class ServiceError(PerceptionError):
    """A service process of the bench did not start, did not answer or died."""


def _undeclare(entity: Any) -> None:
    """Undeclare a subscriber or publisher (unannotated in zenoh-python)."""
    entity.undeclare()


@dataclass(frozen=True, slots=True)
class RawFrame:
    payload: bytes
    attachment: bytes


def raw_frame(image: Image, seq: int) -> RawFrame:
    """A BGRA image as the raw payload + msgpack attachment a camera would put."""
    height, width = image.shape[:2]
    meta = RawFrameMeta(width, height, seq=seq, frame_id="bench")
    return RawFrame(image.tobytes(), meta.to_msgpack())


def raw_frames(scenes: Iterable[Scene]) -> list[RawFrame]:
    """Scenes as the raw BGRA payloads + msgpack attachments a camera would put."""
    return [raw_frame(scene.image, seq) for seq, scene in enumerate(scenes)]


class ServiceProcess:
    """``zenoh-perception run`` as a subprocess: the deployed service, on keys of its own
    (``bench/<name>/...``), listening on a loopback port and dialling the bench's peer.

    Its output goes to a temporary file (a pipe nobody reads could fill up and stall it) and
    is shown when it fails. :meth:`stop` (SIGTERM, then SIGKILL after a timeout) is always
    called by the code that started it.
    """

    def __init__(
        self,
        name: str,
        detector: str,
        bench_endpoint: str,
        dictionary: str = DICTIONARY,
        extra: Sequence[str] = (),
        *,
        input_key: str = "",
    ) -> None:
        self.name = name
        prefix = f"bench/{name}"
        # one key: a second --input-key flag would add a camera, not replace this one
        self.input_key = input_key or f"{prefix}/image"
        self.tag_key = f"{prefix}/tag"
        self.record_key = f"{prefix}/tags"
        self.status_key = f"{prefix}/status"
        self._log = tempfile.TemporaryFile("w+", encoding="utf-8")  # noqa: SIM115 - stop()
        peer = detector in (FLOOR, OPENCV_PEER)
        module = ("zenoh_perception_bench.floor",) if peer else ("zenoh_perception", "run")
        if detector == OPENCV_PEER:
            extra = ("--detect", *extra)
        self.proc = start_service(
            loopback_endpoint(),
            self._log,
            "-e",
            bench_endpoint,
            "--detector",
            detector,
            "--dictionary",
            dictionary,
            "--input-key",
            self.input_key,
            "--tag-key",
            self.tag_key,
            "--record-key",
            self.record_key,
            "--status-key",
            self.status_key,
            "--liveliness-key",
            f"{prefix}/alive",
            "--stats-interval-s",
            "0",
            *extra,  # more flags of ``run``
            module=module,
        )

    def output(self) -> str:
        self._log.flush()
        self._log.seek(0)
        return self._log.read()

    def check(self) -> None:
        """Raise :class:`ServiceError` with the output if the process has exited."""
        code = self.proc.poll()
        if code is not None:
            msg = f"service {self.name!r} exited with {code}:\n{self.output()[-4000:]}"
            raise ServiceError(msg)

    def failure(self, what: str) -> ServiceError:
        return ServiceError(f"service {self.name!r}: {what}; its output:\n{self.output()[-4000:]}")

    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM, then SIGKILL if it has not exited within ``timeout``; the exit code."""
        try:
            if self.proc.poll() is None:
                stop_service(self.proc, timeout)
            return self.proc.returncode
        finally:
            self._log.close()


class Camera:
    """The bench's camera: from shared memory (:class:`ShmPutter`, the default) or plain bytes.

    :meth:`load` is the camera writing its image into the buffer it puts; the bench calls it
    before starting the clock, then times ``put`` -> ``tag``.
    """

    def __init__(self, shm: bool) -> None:
        self.putter = ShmPutter() if shm else None
        self.write_ms: list[float] = []

    def load(self, payload: bytes) -> Loaded:
        if self.putter is None:
            return payload
        start = time.perf_counter()
        loaded = self.putter.load(payload)
        self.write_ms.append((time.perf_counter() - start) * 1e3)
        return loaded

    def summary(self) -> dict[str, Any]:
        """``shm``: frames went from shared memory (``plain_frames`` counts any that did not,
        every buffer of the pool being held at the time; ``unavailable`` says why SHM was not
        used at all)."""
        if self.putter is None:
            return {"shm": False, "put": "bytes (Zenoh copies them on put)"}
        times = np.asarray(self.write_ms, dtype=np.float64)
        return {
            **self.putter.summary(),
            "put": "shared-memory buffer",
            "write_median_ms": rounded(np.median(times)) if times.size else None,
        }


class Remote:
    """The bench's side of one service process: the camera publisher on its input key, the
    consumer subscribers on its ``tag`` and record keys (records are decoded afterwards)."""

    def __init__(self, session: zenoh.Session, service: ServiceProcess) -> None:
        self.service = service
        self._session = session
        self.tags: queue.Queue[float] = queue.Queue()
        self.record_arrivals: queue.Queue[float] = queue.Queue()  # perf_counter() per record
        self._raw_records: list[bytes] = []
        self._lock = threading.Lock()
        self._matched = threading.Event()
        self._subs = [
            session.declare_subscriber(service.tag_key, self._on_tag),
            session.declare_subscriber(service.record_key, self._on_record),
        ]
        # block rather than drop when the link is busy: a frame lost by Zenoh on loopback
        # would count as neither processed nor dropped
        self.publisher = session.declare_publisher(
            service.input_key, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._listener = self.publisher.declare_matching_listener(self._on_matching)

    def _on_tag(self, _sample: zenoh.Sample) -> None:
        self.tags.put(time.perf_counter())

    def _on_record(self, sample: zenoh.Sample) -> None:
        arrived = time.perf_counter()
        with self._lock:
            self._raw_records.append(sample.payload.to_bytes())
        self.record_arrivals.put(arrived)

    def _on_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            self._matched.set()

    def wait_ready(self, timeout: float = STARTUP_TIMEOUT_S) -> None:
        """Until the service's frame subscriber is matched (it declares it last, once every
        other part is up); fails early with the output if the process exits."""
        deadline = time.monotonic() + timeout
        while not self._matched.wait(0.1):
            self.service.check()
            if time.monotonic() > deadline:
                raise self.service.failure(f"no subscriber on {self.service.input_key} in time")

    def warm_up(self, width: int, height: int, camera: Camera) -> None:
        """Put blank frames until one is answered: the whole path is then ready (OpenCV's
        first-call costs paid), and leftovers are drained."""
        meta = RawFrameMeta(width, height, seq=WARMUP_SEQ).to_msgpack()
        blank = RawFrame(bytes(width * height * 4), meta)
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        puts = 0
        while time.monotonic() < deadline:
            self.service.check()
            self.publisher.put(camera.load(blank.payload), attachment=blank.attachment)
            puts += 1
            try:
                self.tags.get(timeout=1.0)
            except queue.Empty:
                continue
            if puts > 1:  # the answer of another warm-up frame may still be on its way
                quiet(self)
            self.drain()
            return
        raise self.service.failure("no answer to warm-up frames")

    def wait_answer(self, timeout: float = ANSWER_TIMEOUT_S) -> float:
        """perf_counter() time at which the next ``tag`` arrived."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                return self.tags.get(timeout=min(1.0, max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                if time.monotonic() >= deadline:
                    raise self.service.failure(f"no tag within {timeout} s") from None
                self.service.check()

    def drain(self) -> None:
        while True:
            try:
                self.tags.get_nowait()
            except queue.Empty:
                return

    def records(self) -> list[dict[str, Any]]:
        """Every record received so far, decoded, warm-up frames left out."""
        with self._lock:
            raw = list(self._raw_records)
        decoded = (msgpack.unpackb(payload, raw=False) for payload in raw)
        return [r for r in decoded if int(r["seq"]) != WARMUP_SEQ]

    def clear_records(self) -> None:
        with self._lock:
            self._raw_records.clear()

    def status(self) -> dict[str, Any]:
        """The service's status (its own counters), from its queryable."""
        replies = query_status(self._session, self.service.status_key, 2.0, gather=False)
        if replies:
            return replies[0]
        self.service.check()
        raise self.service.failure("no status reply")

    def close(self) -> None:
        for entity in (self._listener, *self._subs, self.publisher):
            with suppress(zenoh.ZError):  # already gone with the session
                _undeclare(entity)


@contextmanager
def services(
    names: Sequence[str],
    bench_endpoint: str,
    session: zenoh.Session,
    dictionary: str = DICTIONARY,
    flags: Sequence[str] = (),
) -> Iterator[dict[str, Remote]]:
    """Start one service process per detector name (all at once: start-ups overlap), with
    ``flags`` (more flags of ``run``, e.g. ``-s FILE``) for the services, not the floor; wait
    until each is ready; always stopped and undeclared on exit."""
    processes: list[ServiceProcess] = []
    remotes: dict[str, Remote] = {}
    try:
        for name in names:
            extra = () if name in (FLOOR, OPENCV_PEER) else flags
            processes.append(ServiceProcess(name, name, bench_endpoint, dictionary, extra))
            remotes[name] = Remote(session, processes[-1])
        for remote in remotes.values():
            remote.wait_ready()
        yield remotes
    finally:
        for remote in remotes.values():
            remote.close()
        for process in processes:
            process.stop()


def frames_of(status: dict[str, Any]) -> dict[str, int]:
    """The frame counts of a status reply."""
    frames: dict[str, int] = status["frames"]
    return frames


def is_idle(status: dict[str, Any]) -> bool:
    """Every received frame was processed, dropped or rejected (nothing left in the mailbox)."""
    f = frames_of(status)
    return f["received"] == f["processed"] + f["dropped"] + f["rejected"]


def quiet(remote: Remote, timeout: float = 5.0) -> dict[str, Any]:
    """Service status once nothing has arrived for 0.3 s and everything received is handled."""
    deadline = time.monotonic() + timeout
    last = remote.status()
    still_since = time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.05)
        status = remote.status()
        if frames_of(status)["received"] != frames_of(last)["received"] or not is_idle(status):
            still_since = time.monotonic()
        elif time.monotonic() - still_since >= 0.3:
            return status
        last = status
    return last


def settle(remote: Remote, expected_received: int, timeout: float = 10.0) -> dict[str, Any]:
    """Service status once every frame put has been received and handled (or on timeout)."""
    deadline = time.monotonic() + timeout
    status = remote.status()
    while time.monotonic() < deadline:
        status = remote.status()
        if frames_of(status)["received"] >= expected_received and is_idle(status):
            break
        time.sleep(0.02)
    return status
