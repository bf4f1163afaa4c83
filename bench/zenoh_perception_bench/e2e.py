"""End to end through service processes, in lockstep (:mod:`~zenoh_perception_bench.processes`).

Raw BGRA frames are put one at a time and the next goes when the ``tag`` of the previous one
is back; the timed interval is ``put`` -> ``tag`` callback in the bench. The services run side
by side (each on its own keys) and every frame goes to each in turn, right after OpenCV's
default (:class:`~zenoh_perception_bench.runners.Baseline`) has run on it bare in the bench's
process, the order rotating per frame: a slower or busier moment of the machine affects all of
them alike. Beside the services runs the transport floor
(:data:`~zenoh_perception_bench.processes.FLOOR`): a service's own cost is its end-to-end time
minus the floor's.

Recall, false positives and the per-frame ``timing`` come from the services' records; the
overhead is, per frame, end to end minus the record's ``detect_ms``: everything but the
detector (transport both ways, the copy out of Zenoh, decoding, the grey conversion,
selection, publishing).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.detect.types import Detection
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import (
    Camera,
    Remote,
    frames_of,
    quiet,
    raw_frame,
    services,
    settle,
)
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.runners import DICTIONARY, Baseline, rotation
from zenoh_perception_bench.scene import Scene
from zenoh_perception_bench.scoring import Tally

Image = npt.NDArray[np.uint8]

#: The frame deadline of the generated bench's services. The lockstep waits for every frame's
#: answer, and the deadline is wall time: on a busy machine the default one abandons a frame
#: that is merely slow (no stall), which then never gets an answer. This one is far above any
#: generated frame's time, and the guard stays on, so the services run their default code.
LOCKSTEP_DEADLINE_MS: Final = 20_000


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
    flags: Sequence[str] = (),
) -> LockstepRun:
    """End-to-end latency (frame put -> ``tag`` received) of one service process per name
    (a detector, or the floor), one BGRA image at a time (one stream, in order), and the
    baseline's bare detection time on the same image (see the module doc). With ``shm`` the
    frame is written into a shared-memory buffer before the clock starts (``camera``: one to
    share between runs, whose summary then covers them all). ``flags``: more flags of the
    services' ``run``.
    """
    latencies: dict[str, list[float]] = {name: [] for name in names}
    bare: list[float] = []
    baseline = Baseline(dictionary)
    camera = Camera(shm) if camera is None else camera
    bench_endpoint = loopback_endpoint()
    height, width = images[0].shape[:2]
    with (
        zenoh.open(loopback_config(listen=[bench_endpoint])) as session,
        services(names, bench_endpoint, session, dictionary, flags) as remotes,
    ):
        for remote in remotes.values():
            remote.warm_up(width, height, camera)
        steps: list[str] = ["", *remotes]
        for index, image in enumerate(images):
            frame = raw_frame(image, index)
            for step in rotation(steps, index):
                if not step:
                    bare.append(baseline.run(image)[1])
                    continue
                remote = remotes[step]
                loaded = camera.load(frame.payload)  # the camera's own write, not timed
                start = time.perf_counter()
                remote.publisher.put(loaded, attachment=frame.attachment)
                latencies[step].append((remote.wait_answer() - start) * 1e3)
                del loaded
            tick(progress, label)
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
    """:func:`lockstep_images` on generated scenes (the services' deadline
    :data:`LOCKSTEP_DEADLINE_MS`), each service's records scored against the scenes' truth;
    returns (per service, bare baseline times, camera summary)."""
    run = lockstep_images(
        detectors,
        [s.image for s in scenes],
        progress,
        label,
        shm=shm,
        camera=camera,
        flags=("--frame-deadline-ms", str(LOCKSTEP_DEADLINE_MS)),
    )
    out: dict[str, Lockstep] = {}
    for name, by_seq in run.records.items():
        tally = Tally()
        timing: list[dict[str, float] | None] = []
        for seq, scene in enumerate(scenes):
            record = by_seq.get(seq)
            tally.add(scene, record_detections(record), None)
            timing.append(None if record is None else dict(record["timing"]))
        tally.times_ms = run.latencies_ms[name]
        out[name] = Lockstep(tally, timing)
    return out, run.bare_ms, run.camera


def record_detections(record: dict[str, Any] | None) -> list[Detection]:
    """The tags of a service's record (none for a frame without a record)."""
    if record is None:
        return []
    return [
        Detection(int(tag["tag_id"]), np.asarray(tag["corners"], dtype=np.float32))
        for tag in record["tags"]
    ]


def _records_by_seq(remote: Remote, count: int, timeout: float = 10.0) -> dict[int, Any]:
    """seq -> record for frames 0..count-1, once all are in (or after ``timeout``)."""
    deadline = time.monotonic() + timeout
    while True:
        by_seq = {int(r["seq"]): r for r in remote.records() if int(r["seq"]) < count}
        if len(by_seq) >= count or time.monotonic() >= deadline:
            return by_seq
        time.sleep(0.01)


def paced_images(
    name: str,
    images: Sequence[Image],
    plain: Image,
    *,
    rate_hz: float = 30.0,
    plain_every: int = 4,
    shm: bool = True,
    ids: frozenset[int] = frozenset(),
) -> dict[str, Any]:
    """One service process (detector ``name``) sent ``images`` at ``rate_hz`` as a camera
    would, ``plain`` in place of every ``plain_every``-th frame, without waiting for answers:
    frames answered a second, the in-service latency of the plain frames' answers (ms,
    receipt to ``tag``, the wait behind a frame in progress included), and how many answers
    hold every tag of ``ids``."""
    camera = Camera(shm)
    bench_endpoint = loopback_endpoint()
    height, width = images[0].shape[:2]
    frames = [
        raw_frame(plain if index % plain_every == plain_every - 1 else image, index)
        for index, image in enumerate(images)
    ]
    with (
        zenoh.open(loopback_config(listen=[bench_endpoint])) as session,
        services([name], bench_endpoint, session) as remotes,
    ):
        remote = remotes[name]
        remote.warm_up(width, height, camera)
        before = frames_of(quiet(remote))  # the warm-up's frames are not this run's
        remote.clear_records()
        start = time.perf_counter()
        for index, frame in enumerate(frames):
            loaded = camera.load(frame.payload)
            delay = start + index / rate_hz - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            remote.publisher.put(loaded, attachment=frame.attachment)
            del loaded
        sent_s = time.perf_counter() - start
        after = frames_of(settle(remote, before["received"] + len(frames)))
        records = remote.records()
    plain_ms = [
        float(r["timing"]["latency_ms"])
        for r in records
        if int(r["seq"]) % plain_every == plain_every - 1
    ]
    return {
        "frames": len(frames),
        "rate_hz": rate_hz,
        "answered": len(records),
        "answered_per_s": len(records) / max(sent_s, 1e-9),
        "plain_frames": len(frames) // plain_every,
        "plain_answered": len(plain_ms),
        "plain_latency_median_ms": float(np.median(plain_ms)) if plain_ms else None,
        "plain_latency_max_ms": max(plain_ms) if plain_ms else None,
        "answered_with_tags": sum(
            1 for r in records if ids <= {int(tag["tag_id"]) for tag in r["tags"]}
        ),
        "status_frames": {key: after[key] - before[key] for key in after},
    }
