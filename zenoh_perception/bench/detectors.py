"""``zenoh-perception bench``: the tracking detector against OpenCV's default, side by side.

Baseline: what users would otherwise run, BGRA -> BGR (``cv2.cvtColor``) then
``cv2.aruco.ArucoDetector(DICT_4X4_50, DetectorParameters()).detectMarkers`` on the BGR image;
its time includes the conversion. Project: the ``tracking`` detector
(:mod:`zenoh_perception.detect.tracking`, one per frame set) on the BGRA frame as the service
runs it (:class:`~zenoh_perception.pipeline.TagFinder`), timed the same way. Both run on the
same generated frames (:mod:`zenoh_perception.scene`, exact ground truth), one frame after the
other (alternating which goes first), in one process.

Frame sets (realistic effects: blur, motion blur, noise, lighting, clutter):

- ``VGA`` ... ``HD2K``: independent frames, 4 tags and 2 look-alikes each;
- ``video``: consecutive HD720 frames at 60 Hz (the ZED's HD720 rate) of a rover driving
  toward 4 tags and 2 look-alikes;
- ``distractors``: HD720 frames with 1 tag and 6 look-alikes;
- ``real-camera`` and ``real-camera video``: the same at HD720 with what real cameras add
  (:meth:`~zenoh_perception.scene.Effects.real_camera`: colour casts, JPEG 4:2:0, exposure,
  shadows, glare, greyscale, rolling shutter, strong blur), a quarter of the tags cut by the
  border.

Per set and detector: median / p99 / mean time, recall (visible, unoccluded tags found with
the right id), false positives (reported tags that are not a tag there), median centre error
(pixels, mean of corners against the truth) and median distance error (solvePnP on the
reported corners with the scene's intrinsics and tag size).

End to end, as deployed: each service is the real CLI in its own process
(``zenoh-perception run --detector opencv|fast``, on keys of its own, ``-l`` a loopback port,
multicast scouting off) and the bench process is only the camera and the consumer, one Zenoh
peer that the services dial (the bench listens first, so no connect-retry timer delays a
start). A service is ready once its frame subscriber matches the bench's publisher (it
declares it last) and a warm-up frame has been answered; no fixed sleeps. Raw BGRA frames are
put one at a time and the next goes when the ``tag`` of the previous one is back (lockstep).
The independent HD720 frames and the video each go through ``--passes`` such runs (3 by
default), each with service processes of their own (so each pass starts as cold as one run
does, tracks and caches included), and the passes are pooled: the figure of one pass moves by
several percent from run to run on a shared machine. Each pass's ratio is reported as well.
By default the camera puts each frame from a Zenoh shared-memory buffer
(:class:`~zenoh_perception.camera.shm.ShmPutter`), as a camera on the service's machine does: the
frame is written into its buffer *before* the clock starts (a camera writes its image into its
buffer anyway; the write time is reported as ``write_median_ms``), and the timed interval is
``put`` -> ``tag`` callback in the bench. ``--no-shm`` puts plain ``bytes`` instead, which
Zenoh copies inside the timed interval. The report's ``e2e_setup`` and the printed table say
which was used (and why, if shared memory was unavailable). Recall, false positives and the
per-frame ``timing`` come from the ``perception/tags`` records; the overhead column is, per
frame, end to end minus the record's ``detect_ms``: everything but the detector (transport both
ways, the copy out of Zenoh, decoding, the grey conversion, selection, publishing).

Throughput: HD1080 frames published at 60 Hz for a few seconds to a service process, every
frame must be processed (none dropped by the latest-frame-wins mailbox); counts come from the
service's status queryable, latency (receive -> publish in the service) from its records. It
moved out of the bench's process with the lockstep runs: in-process, the 60 Hz camera, the
consumer callbacks and the service shared one interpreter (GIL), which a deployment never does,
and the subprocess costs one start-up per detector and no other change.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import queue
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import cv2
import msgpack
import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception import __version__
from zenoh_perception.bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception.bench.soak import start_service, stop_service
from zenoh_perception.camera.shm import Loaded, ShmPutter
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import aruco_dictionary, detections_from_opencv
from zenoh_perception.detect.tracking import tracking_counters
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.errors import PerceptionError
from zenoh_perception.pipeline import TagFinder
from zenoh_perception.resolutions import RESOLUTIONS as SCENE_RESOLUTIONS
from zenoh_perception.scene import CameraModel, Effects, Scene, SceneGenerator
from zenoh_perception.tags.pose import Intrinsics, estimate_pose
from zenoh_perception.wire.frames import ENCODINGS, Frame, RawFrameMeta

Image = npt.NDArray[np.uint8]
Handler = Callable[[argparse.Namespace], int]

#: The independent frame sets: every named resolution of the scene generator.
RESOLUTIONS: Final = tuple(SCENE_RESOLUTIONS)
DICTIONARY: Final = "DICT_4X4_50"
BGRA8: Final = ENCODINGS["bgra8"]
VIDEO_RESOLUTION: Final = "HD720"
THROUGHPUT_RESOLUTION: Final = "HD1080"
THROUGHPUT_HZ: Final = 60.0
#: The services measured end to end (``zenoh-perception run --detector NAME``).
E2E_DETECTORS: Final = ("opencv", "tracking")
#: The frame sets measured end to end.
E2E_SETS: Final = (VIDEO_RESOLUTION, "video", "real-camera video")
#: The transport floor, timed beside them (:mod:`zenoh_perception.bench.floor`).
FLOOR: Final = "floor"

# goal thresholds: a service's own cost (end to end - floor) against OpenCV's detection time,
# mean on video and median on independent frames; the median centre error of what it finds
VIDEO_E2E_RATIO: Final = 0.5
INDEPENDENT_E2E_RATIO: Final = 1.0
CENTRE_ERROR_PX: Final = 0.5


@dataclass(frozen=True, slots=True)
class Plan:
    """How much the bench measures."""

    frames: int  # independent frames per resolution
    video_frames: int
    video_fps: float
    distractor_frames: int
    throughput_s: float
    seed: int = 2024
    # end to end: lockstep passes over the HD720 independent frames and over the video, each
    # with service processes of its own (one pass's figure moves by several percent on a
    # shared machine)
    e2e_passes: int = 1

    @classmethod
    def full(cls) -> Plan:
        return cls(
            frames=60,
            video_frames=300,
            video_fps=60.0,
            distractor_frames=40,
            throughput_s=8.0,
            e2e_passes=3,
        )

    @classmethod
    def quick(cls) -> Plan:
        return cls(
            frames=6,
            video_frames=24,
            video_fps=60.0,
            distractor_frames=6,
            throughput_s=1.0,
            e2e_passes=2,
        )


# ------------------------------------------------------------------ progress


class Progress:
    """A one-line progress bar on stderr (``[#####.....]  42/100 label``)."""

    def __init__(self, total: int, stream: Any = None, width: int = 30) -> None:
        self.total = max(total, 1)
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._width = width
        self._last = 0.0
        self._label = ""

    def step(self, label: str | None = None, amount: int = 1) -> None:
        self.done = min(self.done + amount, self.total)
        if label is not None:
            self._label = label
        now = time.monotonic()
        if now - self._last >= 0.1 or self.done == self.total:
            self._last = now
            filled = round(self._width * self.done / self.total)
            bar = "#" * filled + "." * (self._width - filled)
            self._stream.write(f"\r[{bar}] {self.done:4d}/{self.total} {self._label:<40.40}")
            self._stream.flush()

    def close(self) -> None:
        self._stream.write("\n")
        self._stream.flush()


# ------------------------------------------------------------------ scoring


@dataclass(slots=True)
class Tally:
    """What one detector did on one frame set."""

    times_ms: list[float] = field(default_factory=list)
    found: int = 0
    visible: int = 0
    false_positives: int = 0
    centre_errors: list[float] = field(default_factory=list)
    distance_errors: list[float] = field(default_factory=list)

    def extend(self, other: Tally) -> None:
        """Add what ``other`` counted (another pass over frames)."""
        self.times_ms += other.times_ms
        self.found += other.found
        self.visible += other.visible
        self.false_positives += other.false_positives
        self.centre_errors += other.centre_errors
        self.distance_errors += other.distance_errors

    def add(self, scene: Scene, detections: Sequence[Detection], ms: float | None) -> None:
        if ms is not None:
            self.times_ms.append(ms)
        found, visible, false_pos, centre, distance = score(scene, detections)
        self.found += found
        self.visible += visible
        self.false_positives += false_pos
        self.centre_errors += centre
        self.distance_errors += distance

    @property
    def recall(self) -> float:
        return self.found / self.visible if self.visible else 1.0

    def summary(self) -> dict[str, Any]:
        times = np.asarray(self.times_ms, dtype=np.float64)
        out: dict[str, Any] = {
            "frames": int(times.size),
            "median_ms": _r(np.median(times)) if times.size else None,
            "p99_ms": _r(np.percentile(times, 99)) if times.size else None,
            "mean_ms": _r(times.mean()) if times.size else None,
            "recall": round(self.recall, 4),
            "found": self.found,
            "visible": self.visible,
            "false_positives": self.false_positives,
            "centre_error_px": _r(np.median(self.centre_errors)) if self.centre_errors else None,
            "distance_error_pct": (
                _r(100.0 * float(np.median(self.distance_errors))) if self.distance_errors else None
            ),
        }
        return out


def _r(value: Any, digits: int = 3) -> float:
    return round(float(value), digits)


def score(
    scene: Scene, detections: Sequence[Detection]
) -> tuple[int, int, int, list[float], list[float]]:
    """(found, visible, false positives, centre errors, relative distance errors) of a frame.

    A detection is a tag if a tag with its id lies within max(3 px, 30 % of its side) of its
    centre; it counts toward recall when that tag is fully visible and unoccluded (detections
    of partly hidden tags are neither found nor false). Anything else is a false positive.
    """
    camera = scene.camera
    intrinsics = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy)
    targets = [m for m in scene.markers if m.visible and not m.occluded]
    matched: set[int] = set()
    false_pos = 0
    centre: list[float] = []
    distance: list[float] = []
    for det in detections:
        centre_det = np.asarray(det.corners, dtype=np.float64).mean(axis=0)
        hit = None
        for index, marker in enumerate(scene.markers):
            if marker.tag_id != det.tag_id:
                continue
            err = float(np.linalg.norm(centre_det - marker.corner_mean))
            if err <= max(3.0, 0.3 * marker.side_px):
                hit = index
                break
        if hit is None:
            false_pos += 1
            continue
        marker = scene.markers[hit]
        if not (marker.visible and not marker.occluded) or hit in matched:
            continue
        matched.add(hit)
        centre.append(float(np.linalg.norm(centre_det - marker.corner_mean)))
        pose = estimate_pose(det.corners, marker.size_m, intrinsics)
        if pose is not None:
            distance.append(abs(pose.distance_m - marker.distance_m) / marker.distance_m)
    return len(matched), len(targets), false_pos, centre, distance


# ------------------------------------------------------------------ detectors under test


class Baseline:
    """BGRA -> BGR, then OpenCV's default ArUco detector."""

    name = "baseline"

    def __init__(self, dictionary: str = DICTIONARY) -> None:
        params = cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def run(self, image: Image) -> tuple[list[Detection], float]:
        start = time.perf_counter()
        converted = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        corners, ids, _ = self._detector.detectMarkers(converted)
        elapsed = (time.perf_counter() - start) * 1e3
        return detections_from_opencv(corners, ids), elapsed


class Project:
    """A service detector (default: ``tracking``; one per frame set, like one per stream) run
    on the BGRA frame as the service's pipeline runs it (:class:`TagFinder`: grey conversion
    included, tags shorter than ``min_side_px`` dropped)."""

    def __init__(
        self,
        dictionary: str = DICTIONARY,
        detector: Detector | None = None,
        min_side_px: float = 0.0,
    ) -> None:
        self.detector = make_detector("tracking", dictionary) if detector is None else detector
        self._finder = TagFinder(self.detector, min_side_px)

    def run(self, image: Image) -> tuple[list[Detection], float]:
        start = time.perf_counter()
        detections, _ = self._finder.find(Frame(image, BGRA8, None, "bench", None))
        elapsed = (time.perf_counter() - start) * 1e3
        return detections, elapsed


def compare(
    scenes: Sequence[Scene], runners: Sequence[Any], progress: Progress | None, label: str
) -> list[Tally]:
    """Run every runner on every frame (order rotating per frame); one tally per runner."""
    tallies = [Tally() for _ in runners]
    for index, scene in enumerate(scenes):
        order = list(range(len(runners)))
        shift = index % len(order)
        for k in order[shift:] + order[:shift]:
            detections, ms = runners[k].run(scene.image)
            tallies[k].add(scene, detections, ms)
        if progress is not None:
            progress.step(label)
    return tallies


# ------------------------------------------------------------------ frame sets


@dataclass(frozen=True, slots=True)
class FrameSet:
    name: str
    resolution: str
    scenes: list[Scene]
    video: bool = False


def frame_sets(plan: Plan, progress: Progress | None) -> list[FrameSet]:
    """Independent frames per resolution, the video drive, the look-alike frames, and the
    real-camera independent frames and drive."""
    sets: list[FrameSet] = []

    def add(name: str, scenes: Iterable[Scene], resolution: str, *, video: bool = False) -> None:
        collected = []
        for scene in scenes:
            collected.append(scene)
            _tick(progress, f"scenes {name}")
        sets.append(FrameSet(name, resolution, collected, video))

    def generator(resolution: str, seed_offset: int, effects: Effects) -> SceneGenerator:
        camera = CameraModel.named(resolution)
        return SceneGenerator(camera, seed=plan.seed + seed_offset, effects=effects)

    def drive(scenes: SceneGenerator) -> Iterable[Scene]:
        return scenes.drive(plan.video_frames, fps=plan.video_fps, n_tags=4, n_distractors=2)

    for offset, resolution in enumerate(RESOLUTIONS):
        scenes = generator(resolution, offset, Effects.realistic())
        add(resolution, (scenes.random_scene(4, 2) for _ in range(plan.frames)), resolution)
    video = generator(VIDEO_RESOLUTION, 10, Effects.realistic())
    add("video", drive(video), VIDEO_RESOLUTION, video=True)
    lookalikes = generator(VIDEO_RESOLUTION, 20, Effects.realistic())
    add(
        "distractors",
        (lookalikes.random_scene(1, 6) for _ in range(plan.distractor_frames)),
        VIDEO_RESOLUTION,
    )
    real = generator(VIDEO_RESOLUTION, 40, Effects.real_camera())
    # every other frame has a quarter of its tags cut by the border
    add(
        "real-camera",
        (
            real.random_scene(4, 2, partial_fraction=0.25 if index % 2 else 0.0)
            for index in range(plan.frames)
        ),
        VIDEO_RESOLUTION,
    )
    real_drive = generator(VIDEO_RESOLUTION, 50, Effects.real_camera())
    add("real-camera video", drive(real_drive), VIDEO_RESOLUTION, video=True)
    return sets


def _tick(progress: Progress | None, label: str) -> None:
    if progress is not None:
        progress.step(label)


# ------------------------------------------------------------------ end to end (Zenoh)

#: seq of the warm-up frames (never a measured frame's).
WARMUP_SEQ: Final = 10**9
#: A service process must answer within this (start-up imports OpenCV and Zenoh; a busy
#: 2-core machine can take many seconds).
STARTUP_TIMEOUT_S: Final = 90.0
ANSWER_TIMEOUT_S: Final = 30.0


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
        self, name: str, detector: str, bench_endpoint: str, dictionary: str = DICTIONARY
    ) -> None:
        self.name = name
        prefix = f"bench/{name}"
        self.input_key = f"{prefix}/image"
        self.tag_key = f"{prefix}/tag"
        self.record_key = f"{prefix}/tags"
        self.status_key = f"{prefix}/status"
        self._log = tempfile.TemporaryFile("w+", encoding="utf-8")  # noqa: SIM115 - stop()
        module = (
            ("zenoh_perception.bench.floor",) if detector == FLOOR else ("zenoh_perception", "run")
        )
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


class _Remote:
    """The bench's side of one service process: the camera publisher on its input key, the
    consumer subscribers on its ``tag`` and record keys (records are decoded afterwards)."""

    def __init__(self, session: zenoh.Session, service: ServiceProcess) -> None:
        self.service = service
        self._session = session
        self.tags: queue.Queue[float] = queue.Queue()
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
        with self._lock:
            self._raw_records.append(sample.payload.to_bytes())

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
                _quiet(self)
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
        for reply in self._session.get(self.service.status_key, timeout=2.0):
            if reply.ok is not None:
                data: dict[str, Any] = json.loads(reply.ok.payload.to_string())
                return data
        self.service.check()
        raise self.service.failure("no status reply")

    def close(self) -> None:
        for entity in (self._listener, *self._subs, self.publisher):
            with suppress(zenoh.ZError):  # already gone with the session
                _undeclare(entity)


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
            "write_median_ms": _r(np.median(times)) if times.size else None,
        }


@contextmanager
def _services(
    names: Sequence[str],
    bench_endpoint: str,
    session: zenoh.Session,
    dictionary: str = DICTIONARY,
) -> Iterator[dict[str, _Remote]]:
    """Start one service process per detector name (all at once: start-ups overlap), wait
    until each is ready; always stopped and undeclared on exit."""
    processes: list[ServiceProcess] = []
    remotes: dict[str, _Remote] = {}
    try:
        for name in names:
            processes.append(ServiceProcess(name, name, bench_endpoint, dictionary))
            remotes[name] = _Remote(session, processes[-1])
        for remote in remotes.values():
            remote.wait_ready()
        yield remotes
    finally:
        for remote in remotes.values():
            remote.close()
        for process in processes:
            process.stop()


@dataclass(slots=True)
class Lockstep:
    """End-to-end latencies of one service and what its records say (recall, FP, timing)."""

    tally: Tally  # its times are the end-to-end latencies, frame by frame
    timing: list[dict[str, float] | None]  # the record's ``timing`` per frame (None: no record)

    @property
    def latencies_ms(self) -> list[float]:
        return self.tally.times_ms

    def extend(self, other: Lockstep) -> None:
        """Add another pass's frames."""
        self.tally.extend(other.tally)
        self.timing += other.timing

    def overhead_ms(self) -> list[float]:
        """Per frame with a record: end to end minus the service's ``detect_ms``."""
        return [
            e2e - t["detect_ms"]
            for e2e, t in zip(self.latencies_ms, self.timing, strict=True)
            if t is not None
        ]


@dataclass(slots=True)
class LockstepRun:
    """What a lockstep run over plain images measured, per service name."""

    latencies_ms: dict[str, list[float]]  # put -> tag, frame by frame
    records: dict[str, dict[int, Any]]  # seq -> the service's record
    bare_ms: list[float]  # the bare baseline's detection time, frame by frame
    camera: dict[str, Any]  # the camera's summary


def lockstep_images(
    names: Sequence[str],
    images: Sequence[Image],
    progress: Progress | None,
    label: str,
    *,
    dictionary: str = DICTIONARY,
    shm: bool = True,
    camera: Camera | None = None,
) -> LockstepRun:
    """End-to-end latency (frame put -> ``tag`` received) of one service process per name
    (a detector, or :data:`FLOOR`), one BGRA image at a time (one stream, in order), and the
    baseline's bare detection time on the same image.

    The services run side by side (each on its own keys) and every frame goes to each in
    turn, right after the bare baseline has run on it (the order rotates per frame): a
    slower or busier moment of the machine affects all of them alike. With ``shm`` the frame
    is written into a shared-memory buffer before the clock starts (``camera``: one to share
    between runs, whose summary then covers them all).
    """
    latencies: dict[str, list[float]] = {name: [] for name in names}
    bare: list[float] = []
    baseline = Baseline(dictionary)
    camera = Camera(shm) if camera is None else camera
    bench_endpoint = loopback_endpoint()
    height, width = images[0].shape[:2]
    with (
        zenoh.open(loopback_config(listen=[bench_endpoint])) as session,
        _services(names, bench_endpoint, session, dictionary) as remotes,
    ):
        for remote in remotes.values():
            remote.warm_up(width, height, camera)
        steps: list[str] = ["", *remotes]
        for index, image in enumerate(images):
            frame = raw_frame(image, index)
            shift = index % len(steps)
            for step in steps[shift:] + steps[:shift]:
                if not step:
                    bare.append(baseline.run(image)[1])
                    continue
                remote = remotes[step]
                loaded = camera.load(frame.payload)  # the camera's own write, not timed
                start = time.perf_counter()
                remote.publisher.put(loaded, attachment=frame.attachment)
                latencies[step].append((remote.wait_answer() - start) * 1e3)
                del loaded
            _tick(progress, label)
        records = {name: _records_by_seq(r, len(images)) for name, r in remotes.items()}
    return LockstepRun(latencies, records, bare, camera.summary())


def lockstep(
    detectors: Sequence[str],
    scenes: Sequence[Scene],
    progress: Progress | None,
    label: str,
    *,
    shm: bool = True,
    camera: Camera | None = None,
) -> tuple[dict[str, Lockstep], list[float], dict[str, Any]]:
    """:func:`lockstep_images` on generated scenes, each service's records scored against the
    scenes' truth; returns (per service, bare baseline times, camera summary)."""
    run = lockstep_images(
        detectors, [s.image for s in scenes], progress, label, shm=shm, camera=camera
    )
    out: dict[str, Lockstep] = {}
    for name, by_seq in run.records.items():
        tally = Tally()
        timing: list[dict[str, float] | None] = []
        for seq, scene in enumerate(scenes):
            record = by_seq.get(seq)
            tally.add(scene, _detections(record), None)
            timing.append(None if record is None else dict(record["timing"]))
        tally.times_ms = run.latencies_ms[name]
        out[name] = Lockstep(tally, timing)
    return out, run.bare_ms, run.camera


def _records_by_seq(remote: _Remote, count: int, timeout: float = 10.0) -> dict[int, Any]:
    """seq -> record for frames 0..count-1, once all are in (or after ``timeout``)."""
    deadline = time.monotonic() + timeout
    while True:
        by_seq = {int(r["seq"]): r for r in remote.records() if int(r["seq"]) < count}
        if len(by_seq) >= count or time.monotonic() >= deadline:
            return by_seq
        time.sleep(0.01)


def _detections(record: dict[str, Any] | None) -> list[Detection]:
    if record is None:
        return []
    return [
        Detection(int(tag["tag_id"]), np.asarray(tag["corners"], dtype=np.float32))
        for tag in record["tags"]
    ]


def throughput(
    detector: str,
    frames: Sequence[RawFrame],
    *,
    rate_hz: float,
    seconds: float,
    progress: Progress | None,
    label: str,
    shm: bool = True,
) -> dict[str, Any]:
    """Publish ``frames`` (cycled forward and back) at ``rate_hz`` for ``seconds`` to a service
    process; counts from its status queryable, latency (receive -> publish) from its records."""
    order = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))
    count = max(1, round(rate_hz * seconds))
    height, width = _frame_size(frames[0])
    camera = Camera(shm)
    bench_endpoint = loopback_endpoint()
    with (
        zenoh.open(loopback_config(listen=[bench_endpoint])) as session,
        _services([detector], bench_endpoint, session) as remotes,
    ):
        remote = remotes[detector]
        remote.warm_up(width, height, camera)
        before = _quiet(remote)  # warm-up frames still in flight must not count
        remote.clear_records()
        start = time.perf_counter()
        late = 0
        for i in range(count):
            due = start + i / rate_hz
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.5 / rate_hz:
                late += 1
            frame = frames[order[i % len(order)]]
            remote.publisher.put(camera.load(frame.payload), attachment=frame.attachment)
            _tick(progress, label)
        published_s = time.perf_counter() - start
        stats = _settle(remote, _count(before, "received") + count)
        latency = [float(r["timing"]["latency_ms"]) for r in remote.records()]
    received = _count(stats, "received") - _count(before, "received")
    processed = _count(stats, "processed") - _count(before, "processed")
    dropped = _count(stats, "dropped") - _count(before, "dropped")
    return {
        "resolution": f"{width}x{height}",
        "rate_hz": rate_hz,
        "published": count,
        "publish_s": _r(published_s),
        "late_puts": late,
        "received": received,
        "processed": processed,
        "dropped": dropped,
        "processed_hz": _r(processed / published_s if published_s > 0 else 0.0),
        "latency_p50_ms": _r(np.percentile(latency, 50)) if latency else None,
        "latency_p99_ms": _r(np.percentile(latency, 99)) if latency else None,
        "camera": camera.summary(),
    }


def _frame_size(frame: RawFrame) -> tuple[int, int]:
    meta = msgpack.unpackb(frame.attachment, raw=False)
    return int(meta["height"]), int(meta["width"])


def _count(status: dict[str, Any], name: str) -> int:
    return int(status["frames"][name])


def _handled(status: dict[str, Any]) -> int:
    return sum(_count(status, k) for k in ("processed", "dropped", "rejected"))


def _quiet(remote: _Remote, timeout: float = 5.0) -> dict[str, Any]:
    """Service status once nothing has arrived for 0.3 s and everything received is handled."""
    deadline = time.monotonic() + timeout
    last = remote.status()
    still_since = time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.05)
        status = remote.status()
        if _count(status, "received") != _count(last, "received") or _handled(status) < _count(
            status, "received"
        ):
            still_since = time.monotonic()
        elif time.monotonic() - still_since >= 0.3:
            return status
        last = status
    return last


def _settle(remote: _Remote, expected_received: int, timeout: float = 10.0) -> dict[str, Any]:
    """Service status once every frame put has been received and handled (or on timeout)."""
    deadline = time.monotonic() + timeout
    status = remote.status()
    while time.monotonic() < deadline:
        status = remote.status()
        received = _count(status, "received")
        if received >= expected_received and _handled(status) >= received:
            break
        time.sleep(0.02)
    return status


# ------------------------------------------------------------------ the bench


def run_bench(plan: Plan, *, with_e2e: bool = True, shm: bool = True) -> dict[str, Any]:
    """Measure everything; returns the JSON-ready report (see the module doc). ``shm``: the
    end-to-end camera puts frames from shared memory (else plain bytes)."""
    work = (len(RESOLUTIONS) * plan.frames + plan.video_frames + plan.distractor_frames) * 2
    work += (plan.frames + plan.video_frames) * 2
    if with_e2e:
        work += (plan.frames + 2 * plan.video_frames) * max(1, plan.e2e_passes)
        work += 2 * round(THROUGHPUT_HZ * plan.throughput_s) + 30
    progress = Progress(work)
    try:
        report = _measure(plan, progress, with_e2e=with_e2e, shm=shm)
    finally:
        progress.close()
    return report


def _measure(plan: Plan, progress: Progress, *, with_e2e: bool, shm: bool) -> dict[str, Any]:
    sets = frame_sets(plan, progress)
    report: dict[str, Any] = {
        "version": __version__,
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "opencv": cv2.__version__,
            "opencv_threads": cv2.getNumThreads(),
            "load_average": [round(v, 2) for v in os.getloadavg()],
        },
        "plan": {
            "frames_per_resolution": plan.frames,
            "video_frames": plan.video_frames,
            "video_fps": plan.video_fps,
            "distractor_frames": plan.distractor_frames,
            "throughput_s": plan.throughput_s,
            "seed": plan.seed,
            "e2e_passes": plan.e2e_passes,
        },
        "sets": {},
    }
    for frame_set in sets:
        project = Project()
        baseline_tally, project_tally = compare(
            frame_set.scenes, [Baseline(), project], progress, f"detect {frame_set.name}"
        )
        report["sets"][frame_set.name] = {
            "resolution": frame_set.resolution,
            "video": frame_set.video,
            "baseline": baseline_tally.summary(),
            "tracking": project_tally.summary(),
            "tracking_counters": tracking_counters(project.detector),
        }
    if with_e2e:
        report["e2e"] = _end_to_end(sets, progress, shm=shm, passes=plan.e2e_passes)
        report["throughput"] = _throughput(plan, progress, shm=shm)
        report["e2e_setup"] = _e2e_setup(report, shm)
    report["goals"] = goals(report)
    return report


def _end_to_end(
    sets: Sequence[FrameSet], progress: Progress, *, shm: bool, passes: int
) -> dict[str, Any]:
    """Lockstep runs on the video and on the independent HD720 frames, ``passes`` of each,
    pooled (each pass's ratio is reported too)."""
    out: dict[str, Any] = {}
    for frame_set in sets:
        if frame_set.name not in E2E_SETS:
            continue
        camera = Camera(shm)
        runs: dict[str, Lockstep] = {}
        bare: list[float] = []
        ratios: dict[str, list[float]] = {name: [] for name in E2E_DETECTORS}
        for _ in range(max(1, passes)):
            these, bare_pass, summary = lockstep(
                (*E2E_DETECTORS, FLOOR),
                frame_set.scenes,
                progress,
                f"e2e {frame_set.name}",
                shm=shm,
                camera=camera,
            )
            # the statistic of the set's goal: means on the video, else medians
            stat = np.mean if frame_set.video else np.median
            floor = stat(these[FLOOR].latencies_ms)
            for name in E2E_DETECTORS:
                own = stat(these[name].latencies_ms) - floor
                ratios[name].append(_r(own / stat(bare_pass)))
            for name, run in these.items():
                if name in runs:
                    runs[name].extend(run)
                else:
                    runs[name] = run
            bare += bare_pass
        entry: dict[str, Any] = {"passes": max(1, passes), "pass_ratios": ratios}
        for name, run in runs.items():
            entry[name] = _e2e_summary(run)
        bare_times = np.asarray(bare)
        entry["baseline_detection"] = {
            "median_ms": _r(np.median(bare_times)),
            "mean_ms": _r(bare_times.mean()),
            "p99_ms": _r(np.percentile(bare_times, 99)),
        }
        entry["camera"] = summary
        out[frame_set.name] = entry
    return out


def _e2e_setup(report: dict[str, Any], shm: bool) -> dict[str, Any]:
    """How the end-to-end figures were made; ``shm`` is whether every frame really went from
    shared memory (requested and available)."""
    cameras = [entry["camera"] for entry in report["e2e"].values()]
    cameras += [run["camera"] for run in report["throughput"].values()]
    fallbacks = sorted({c["unavailable"] for c in cameras if c.get("unavailable")})
    used = shm and all(c["shm"] for c in cameras)
    plain = sum(c.get("plain_frames", 0) for c in cameras) if used else None
    return {
        "services": "zenoh-perception run, one subprocess per detector (--detector "
        + " / ".join(E2E_DETECTORS)
        + ")",
        "transport": "Zenoh peers over tcp/127.0.0.1, multicast scouting off",
        "shm_requested": shm,
        "shm": used,
        "camera_put": (
            "shared memory (frame written into its buffer before the clock starts"
            + (f"; {plain} frames as plain bytes, every buffer held" if plain else "")
            + ")"
            if used
            else "plain bytes (Zenoh copies them on put, inside the timed interval)"
        ),
        "shm_fallback": fallbacks[0] if fallbacks else None,
        "shm_plain_frames": plain,  # frames put as bytes although SHM was in use (pool held)
        "timed": "put -> tag received (lockstep; bench process = camera + consumer)",
        "overhead": "end to end - the record's detect_ms (transport, copy, decode, grey "
        "conversion, selection, publish)",
    }


def _e2e_summary(run: Lockstep) -> dict[str, Any]:
    """Recall / FP from the records, e2e times, and what the records say the time went to."""
    summary = run.tally.summary()  # its times are the end-to-end latencies
    summary["records"] = sum(t is not None for t in run.timing)
    for key in ("detect_ms", "convert_ms", "decode_ms", "queue_ms", "latency_ms"):
        values = np.asarray([t[key] for t in run.timing if t is not None], dtype=np.float64)
        name = "in_service" if key == "latency_ms" else key.removesuffix("_ms")
        summary[f"{name}_median_ms"] = _r(np.median(values)) if values.size else None
        summary[f"{name}_mean_ms"] = _r(values.mean()) if values.size else None
    overhead = np.asarray(run.overhead_ms(), dtype=np.float64)
    summary["overhead_median_ms"] = _r(np.median(overhead)) if overhead.size else None
    summary["overhead_mean_ms"] = _r(overhead.mean()) if overhead.size else None
    return summary


def _throughput(plan: Plan, progress: Progress, *, shm: bool) -> dict[str, Any]:
    generator = SceneGenerator(
        CameraModel.named(THROUGHPUT_RESOLUTION), seed=plan.seed + 30, effects=Effects.realistic()
    )
    count = max(2, min(90, round(THROUGHPUT_HZ * plan.throughput_s)))
    frames = raw_frames(generator.drive(count, fps=THROUGHPUT_HZ, n_tags=4, n_distractors=2))
    progress.step("throughput frames", 30)
    out: dict[str, Any] = {}
    for name in E2E_DETECTORS:
        out[name] = throughput(
            name,
            frames,
            rate_hz=THROUGHPUT_HZ,
            seconds=plan.throughput_s,
            progress=progress,
            label=f"60 Hz {name}",
            shm=shm,
        )
    return out


# ------------------------------------------------------------------ goals


def own_cost_ms(entry: dict[str, Any], who: str, stat: str) -> float:
    """A service's own cost in an end-to-end entry: its ``stat`` (``median_ms`` or
    ``mean_ms``) end to end minus the transport floor's."""
    return float(entry[who][stat]) - float(entry[FLOOR][stat])


def goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Every goal with its measured value, threshold and PASS / FAIL."""
    sets = report["sets"]
    rows: list[dict[str, Any]] = []

    def goal(name: str, value: float | None, limit: str, passed: bool, note: str = "") -> None:
        rows.append(
            {
                "goal": name,
                "value": None if value is None else _r(value),
                "threshold": limit,
                "pass": bool(passed),
                "note": note,
            }
        )

    for name, entry in sets.items():
        found, base = entry["tracking"]["found"], entry["baseline"]["found"]
        goal(f"{name}: tags found >= OpenCV default", found, f">= {base}", found >= base)
        fp, base_fp = entry["tracking"]["false_positives"], entry["baseline"]["false_positives"]
        goal(f"{name}: false ids <= OpenCV default", fp, f"<= {base_fp}", fp <= base_fp)
    errors = [s["tracking"]["centre_error_px"] for s in sets.values()]
    worst = max((e for e in errors if e is not None), default=math.inf)
    goal(
        "median centre error, worst set (px)",
        worst,
        f"<= {CENTRE_ERROR_PX}",
        worst <= CENTRE_ERROR_PX,
    )
    e2e = report.get("e2e")
    if e2e is not None:
        for set_name, stat, limit in (
            ("video", "mean_ms", VIDEO_E2E_RATIO),
            ("real-camera video", "mean_ms", VIDEO_E2E_RATIO),
            (VIDEO_RESOLUTION, "median_ms", INDEPENDENT_E2E_RATIO),
        ):
            entry = e2e[set_name]
            bare = entry["baseline_detection"][stat]
            own = own_cost_ms(entry, "tracking", stat)
            word = stat.removesuffix("_ms")
            goal(
                f"{set_name}: service {word} e2e - floor / OpenCV {word} detection",
                own / bare,
                f"<= {limit}",
                own / bare <= limit,
                f"{own:.2f} ms vs {bare:.2f} ms; raw e2e {entry['tracking'][stat]:.2f} ms, "
                f"floor {entry[FLOOR][stat]:.2f} ms; {_passes_note(entry)}",
            )
            found = entry["tracking"]["found"]
            base = sets[set_name]["baseline"]["found"] * entry["passes"]
            goal(
                f"{set_name}: tags found by the service (records) >= OpenCV default",
                found,
                f">= {base}",
                found >= base,
            )
    throughput_report = report.get("throughput")
    if throughput_report is not None:
        default = throughput_report["tracking"]
        goal(
            "HD1080 at 60 Hz: every frame processed",
            default["processed"],
            f"== {default['published']} published, 0 dropped",
            default["processed"] == default["published"] and default["dropped"] == 0,
            f"dropped {default['dropped']}, {default['processed_hz']:.1f} Hz",
        )
    return rows


def _passes_note(entry: dict[str, Any]) -> str:
    if entry["passes"] == 1:
        return "one pass"
    each = ", ".join(f"{r:.2f}" for r in entry["pass_ratios"]["tracking"])
    return f"{entry['passes']} passes pooled, own-cost ratio of each: {each}"


# ------------------------------------------------------------------ output


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(out)


def _fmt(value: Any, spec: str = ".2f") -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return format(value, spec)
    return str(value)


def format_report(report: dict[str, Any]) -> str:
    """The human-readable tables."""
    parts = []
    rows = []
    for name, entry in report["sets"].items():
        for who in ("baseline", "tracking"):
            s = entry[who]
            rows.append(
                [
                    name,
                    who,
                    _fmt(s["median_ms"]),
                    _fmt(s["p99_ms"]),
                    _fmt(s["mean_ms"]),
                    f"{s['recall']:.3f} ({s['found']}/{s['visible']})",
                    str(s["false_positives"]),
                    _fmt(s["centre_error_px"], ".3f"),
                    _fmt(s["distance_error_pct"], ".2f"),
                ]
            )
    headers = [
        "set",
        "detector",
        "median ms",
        "p99 ms",
        "mean ms",
        "recall",
        "FP",
        "centre px",
        "dist err %",
    ]
    parts.append(
        "Detection (BGRA frame in, tags out; same frames, one process)\n" + _table(headers, rows)
    )
    if "e2e" in report:
        rows = []
        pass_lines = []
        for set_name, entry in report["e2e"].items():
            name = set_name if entry["passes"] == 1 else f"{set_name} x{entry['passes']}"
            if entry["passes"] > 1:
                each = "; ".join(
                    f"{who} " + ", ".join(f"{r:.2f}" for r in entry["pass_ratios"][who])
                    for who in E2E_DETECTORS
                )
                stat = "mean" if report["sets"][set_name]["video"] else "median"
                pass_lines.append(
                    f"\n{set_name}: {entry['passes']} passes over its frames, each with fresh"
                    f" service processes, pooled above; {stat} own cost (e2e - floor) / bare"
                    f" {stat} per pass: {each}"
                )
            bare = entry["baseline_detection"]
            rows.append(
                [
                    name,
                    "bare baseline",
                    _fmt(bare["median_ms"]),
                    _fmt(bare["mean_ms"]),
                    _fmt(bare["p99_ms"]),
                    "-",
                    "-",
                    "-",
                    "-",
                    "-",
                ]
            )
            for who in (*E2E_DETECTORS, FLOOR):
                s = entry[who]
                rows.append(
                    [
                        name,
                        f"service {who}",
                        _fmt(s["median_ms"]),
                        _fmt(s["mean_ms"]),
                        _fmt(s["p99_ms"]),
                        _fmt(s["detect_median_ms"]),
                        _fmt(s["overhead_median_ms"]),
                        _fmt(s["overhead_mean_ms"]),
                        f"{s['recall']:.3f}",
                        str(s["false_positives"]),
                    ]
                )
        setup = report.get("e2e_setup", {})
        note = f"; camera put: {setup['camera_put']}" if "camera_put" in setup else ""
        if setup.get("shm_fallback"):
            note += f" (shared memory unavailable: {setup['shm_fallback']})"
        parts.append(
            "End to end through the service (put -> tag, lockstep; each service is its own"
            " `zenoh-perception run` process, Zenoh peers over loopback; the bare baseline ran"
            f" on each frame in turn with the services{note}; overhead = e2e - the service's"
            " detect_ms)\n"
            + _table(
                [
                    "frames",
                    "detector",
                    "median ms",
                    "mean ms",
                    "p99 ms",
                    "detect med",
                    "overhead med",
                    "overhead mean",
                    "recall",
                    "FP",
                ],
                rows,
            )
            + "".join(pass_lines)
        )
    if "throughput" in report:
        rows = []
        for who, t in report["throughput"].items():
            rows.append(
                [
                    who,
                    t["resolution"],
                    f"{t['rate_hz']:.0f}",
                    str(t["published"]),
                    str(t["processed"]),
                    str(t["dropped"]),
                    f"{t['processed_hz']:.1f}",
                    _fmt(t["latency_p50_ms"]),
                    _fmt(t["latency_p99_ms"]),
                ]
            )
        parts.append(
            "Throughput (frames published at a fixed rate to a service process; latency ="
            " receive -> publish in the service)\n"
            + _table(
                [
                    "detector",
                    "size",
                    "Hz",
                    "published",
                    "processed",
                    "dropped",
                    "proc Hz",
                    "lat p50",
                    "lat p99",
                ],
                rows,
            )
        )
    rows = [
        [
            g["goal"],
            _fmt(g["value"], ".3f"),
            g["threshold"],
            "PASS" if g["pass"] else "FAIL",
            g["note"],
        ]
        for g in report["goals"]
    ]
    parts.append("Goals\n" + _table(["goal", "value", "threshold", "result", "note"], rows))
    return "\n\n".join(parts)


def plot(report: dict[str, Any], path: Path) -> None:
    """PNG of detection latency (median solid, p99 dashed) against resolution."""
    width, height = 960, 600
    left, right, top, bottom = 90, 40, 60, 90
    canvas = np.full((height, width, 3), 255, dtype=np.uint8)
    names = [n for n in RESOLUTIONS if n in report["sets"]]
    series = []
    for who, colour in (("baseline", (40, 40, 220)), ("tracking", (200, 110, 20))):
        med = [report["sets"][n][who]["median_ms"] or 0.0 for n in names]
        p99 = [report["sets"][n][who]["p99_ms"] or 0.0 for n in names]
        series.append((who, colour, med, p99))
    top_ms = max(max(p99) for _, _, _, p99 in series) * 1.1 or 1.0
    plot_w, plot_h = width - left - right, height - top - bottom

    def xy(i: int, ms: float) -> tuple[int, int]:
        x = left + round(plot_w * (i + 0.5) / len(names))
        y = top + plot_h - round(plot_h * ms / top_ms)
        return x, y

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.rectangle(canvas, (left, top), (left + plot_w, top + plot_h), (0, 0, 0), 1)
    step = _nice_step(top_ms / 6)
    tick = 0.0
    while tick <= top_ms:
        y = xy(0, tick)[1]
        cv2.line(canvas, (left, y), (left + plot_w, y), (225, 225, 225), 1)
        cv2.putText(canvas, f"{tick:g}", (left - 60, y + 5), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        tick += step
    for i, name in enumerate(names):
        x = xy(i, 0)[0]
        cv2.putText(canvas, name, (x - 30, top + plot_h + 30), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for _who, colour, med, p99 in series:
        points = [xy(i, v) for i, v in enumerate(med)]
        for a, b in itertools.pairwise(points):
            cv2.line(canvas, a, b, colour, 2, cv2.LINE_AA)
        for p in points:
            cv2.circle(canvas, p, 5, colour, -1, cv2.LINE_AA)
        points = [xy(i, v) for i, v in enumerate(p99)]
        for a, b in itertools.pairwise(points):
            _dashed(canvas, a, b, colour)
    cv2.putText(
        canvas,
        "Detection latency vs resolution (median solid, p99 dashed)",
        (left, 35),
        font,
        0.7,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    cv2.putText(canvas, "ms", (left - 60, top - 12), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (who, colour, _, _) in enumerate(series):
        y = top + 25 + 25 * k
        cv2.line(canvas, (left + 20, y), (left + 60, y), colour, 2, cv2.LINE_AA)
        text = (
            "baseline (BGRA->BGR + OpenCV defaults)" if who == "baseline" else "tracking (default)"
        )
        cv2.putText(canvas, text, (left + 70, y + 5), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), canvas):
        msg = f"cannot write {path}"
        raise OSError(msg)


def _nice_step(raw: float) -> float:
    exponent = math.floor(math.log10(raw)) if raw > 0 else 0
    unit = 10.0**exponent
    for mult in (1.0, 2.0, 5.0):
        if mult * unit >= raw:
            return mult * unit
    return 10.0 * unit


def _dashed(
    canvas: Image, a: tuple[int, int], b: tuple[int, int], colour: tuple[int, int, int]
) -> None:
    length = math.hypot(b[0] - a[0], b[1] - a[1])
    dashes = max(int(length // 10), 1)
    for k in range(0, dashes, 2):
        t0, t1 = k / dashes, min((k + 1) / dashes, 1.0)
        p = (round(a[0] + (b[0] - a[0]) * t0), round(a[1] + (b[1] - a[1]) * t0))
        q = (round(a[0] + (b[0] - a[0]) * t1), round(a[1] + (b[1] - a[1]) * t1))
        cv2.line(canvas, p, q, colour, 1, cv2.LINE_AA)


# ------------------------------------------------------------------ CLI


@contextmanager
def _sigterm_exits() -> Iterator[None]:
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


def main(args: argparse.Namespace) -> int:
    plan = Plan.quick() if args.quick else Plan.full()
    changes: dict[str, Any] = {}
    if args.frames is not None:
        changes["frames"] = max(1, args.frames)
    if args.video_frames is not None:
        changes["video_frames"] = max(2, args.video_frames)
    if args.seed is not None:
        changes["seed"] = args.seed
    if args.passes is not None:
        changes["e2e_passes"] = max(1, args.passes)
    if changes:
        plan = replace(plan, **changes)
    with _sigterm_exits():
        report = run_bench(plan, with_e2e=not args.no_e2e, shm=not args.no_shm)
    print(format_report(report))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    if args.plot is not None:
        plot(report, args.plot)
    return 0 if all(g["pass"] for g in report["goals"]) else 1
