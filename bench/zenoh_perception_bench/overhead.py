"""``bench --overhead``: what the service adds to OpenCV, in milliseconds, per frame size.

Per resolution (VGA, HD720, HD1080, HD2K; 1-4 tags a frame), and on HD720 frames of 1-6 tags
with two look-alikes each (where the veto has detections to read besides the selected tag's,
which the record waits for), each frame goes in lockstep,
the order rotating per frame, to OpenCV's default bare (in the bench's process), and through
Zenoh to the transport floor and to ``zenoh-perception run`` (OpenCV's detector), once from a
shared-memory camera and once as plain bytes (:class:`~zenoh_perception_bench.processes.Camera`).
Timed: put -> ``tag`` and put -> record (the record follows the tag); the service runs with the
lockstep's frame deadline (:data:`~zenoh_perception_bench.e2e.LOCKSTEP_DEADLINE_MS`: a busy
machine's default 400 ms of wall time abandons frames that are merely slow, which the lockstep
would wait for in vain; the guard stays on). The overhead is a path's
median minus bare OpenCV's median on the same frames; "own" is the service minus the floor
and OpenCV, to ``tag`` and to the record.

Bare OpenCV in the bench's process reads each frame hot, while the service's process has idled
since its last frame (the bench was timing the other paths); on a virtual machine whose CPU
sleeps when idle, a read after 20 ms of idle takes up to twice a hot one's time, which "own"
then counts as the service's. So a third process is timed the same way as the service: the
floor reading each frame with OpenCV's default in its callback before it answers
(:data:`~zenoh_perception_bench.processes.OPENCV_PEER`), idle between frames as the service is.
"vs peer" is the service minus that peer, to ``tag`` and to the record: what the service adds
to OpenCV's default and the transport in the same conditions, which the goals at HD720 judge
(:data:`OWN_TAG_GOAL_MS`, :data:`OWN_RECORD_GOAL_MS`).

``--rate 60`` adds the HD1080 run at a fixed rate (:func:`paced`): frames put every 1/60 s
whatever the answers, for each service detector; how many frames each answers, and its own
detection time per frame (which is what limits it: newest frame wins, the rest are dropped).
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import time
from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.e2e import LOCKSTEP_DEADLINE_MS
from zenoh_perception_bench.processes import (
    E2E_DETECTORS,
    FLOOR,
    OPENCV_PEER,
    Camera,
    Remote,
    raw_frame,
    services,
)
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.runners import DICTIONARY, Baseline, rotation
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator

Image = npt.NDArray[np.uint8]

SERVICE: Final = "opencv"
CAMERAS: Final = ("shm", "bytes")
RECORD_TIMEOUT_S: Final = 10.0
#: The frame sets' names: a resolution, and HD720 with look-alikes.
LOOKALIKES: Final = "HD720 look-alikes"
#: What the service may add to OpenCV and the floor at HD720, ms, to ``tag`` and the record.
OWN_TAG_GOAL_MS: Final = 0.3
OWN_RECORD_GOAL_MS: Final = 0.5


def frames_at(resolution: str, count: int, seed: int, *, lookalikes: bool = False) -> list[Image]:
    """BGRA frames of ``resolution`` with realistic effects: 1-4 tags each, or with
    ``lookalikes`` 1-6 tags and two look-alikes each."""
    scenes = SceneGenerator(CameraModel.named(resolution), seed=seed, effects=Effects.realistic())
    if lookalikes:
        return [scenes.random_scene(1 + index % 6, 2).image for index in range(count)]
    return [scenes.random_scene(1 + index % 4, 0).image for index in range(count)]


def _median(values: Sequence[float]) -> float:
    return float(np.median(np.asarray(values, dtype=np.float64))) if values else float("nan")


def _record_after(remote: Remote, start: float) -> float:
    """Milliseconds from ``start`` to the record's arrival."""
    try:
        return (remote.record_arrivals.get(timeout=RECORD_TIMEOUT_S) - start) * 1e3
    except queue.Empty:
        raise remote.service.failure("no record in time") from None


def _drain(remote: Remote) -> None:
    remote.drain()
    while not remote.record_arrivals.empty():
        remote.record_arrivals.get_nowait()


def lockstep_sizes(
    frames: dict[str, list[Image]], progress: Progress | None, flags: Sequence[str] = ()
) -> dict[str, dict[str, list[float]]]:
    """resolution -> path -> milliseconds per frame (paths: ``opencv bare``, and per camera
    ``floor/tag``, ``opencv-peer/tag``, ``opencv/tag``, ``opencv/record``). ``flags``: more
    flags of the service's ``run``."""
    cameras = {name: Camera(name == "shm") for name in CAMERAS}
    baseline = Baseline(DICTIONARY)
    endpoint = loopback_endpoint()
    out: dict[str, dict[str, list[float]]] = {}
    with (
        zenoh.open(loopback_config(listen=[endpoint])) as session,
        services((FLOOR, OPENCV_PEER, SERVICE), endpoint, session, flags=flags) as remotes,
    ):
        for resolution, images in frames.items():
            height, width = images[0].shape[:2]
            for remote in remotes.values():
                for camera in cameras.values():
                    remote.warm_up(width, height, camera)
                time.sleep(0.2)  # the warm-ups' records
                _drain(remote)
            times: dict[str, list[float]] = {"opencv bare": []}
            steps = ["", *(f"{r}@{c}" for r in remotes for c in cameras)]
            for index, image in enumerate(images):
                frame = raw_frame(image, index)
                for step in rotation(steps, index):
                    if not step:
                        times["opencv bare"].append(baseline.run(image)[1])
                        continue
                    name, camera_name = step.split("@")
                    remote = remotes[name]
                    loaded = cameras[camera_name].load(frame.payload)
                    start = time.perf_counter()
                    remote.publisher.put(loaded, attachment=frame.attachment)
                    tag = (remote.wait_answer() - start) * 1e3
                    record = _record_after(remote, start)
                    del loaded
                    times.setdefault(f"{name}/tag {camera_name}", []).append(tag)
                    times.setdefault(f"{name}/record {camera_name}", []).append(record)
                tick(progress, f"overhead {resolution}")
            out[resolution] = times
    return out


def overhead_rows(by_size: dict[str, dict[str, list[float]]]) -> list[dict[str, Any]]:
    """Per resolution and camera: medians (ms) and the excess over bare OpenCV."""
    rows = []
    for resolution, times in by_size.items():
        bare = _median(times["opencv bare"])
        for camera in CAMERAS:
            floor = _median(times[f"{FLOOR}/tag {camera}"])
            peer = _median(times[f"{OPENCV_PEER}/tag {camera}"])
            peer_record = _median(times[f"{OPENCV_PEER}/record {camera}"])
            tag = _median(times[f"{SERVICE}/tag {camera}"])
            record = _median(times[f"{SERVICE}/record {camera}"])
            rows.append(
                {
                    "resolution": resolution,
                    "camera": camera,
                    "frames": len(times["opencv bare"]),
                    "bare_ms": round(bare, 3),
                    "floor_ms": round(floor, 3),
                    "tag_ms": round(tag, 3),
                    "record_ms": round(record, 3),
                    "tag_over_bare_ms": round(tag - bare, 3),
                    "record_over_bare_ms": round(record - bare, 3),
                    "tag_ratio": round(tag / bare, 2),
                    "own_ms": round(tag - floor - bare, 3),
                    "own_record_ms": round(record - floor - bare, 3),
                    "peer_ms": round(peer, 3),
                    "vs_peer_ms": round(tag - peer, 3),
                    "vs_peer_record_ms": round(record - peer_record, 3),
                }
            )
    return rows


def paced(
    detectors: Sequence[str],
    images: Sequence[Image],
    hz: float,
    seconds: float,
    flags: Sequence[str] = (),
) -> dict[str, dict[str, Any]]:
    """Frames put every 1/hz s (shared memory, newest wins in the service) to one service per
    detector, one after the other; per detector: frames put, ``tag`` answers, the median
    ``detect_ms`` of its records and the rate that allows."""
    out: dict[str, dict[str, Any]] = {}
    endpoint = loopback_endpoint()
    height, width = images[0].shape[:2]
    with zenoh.open(loopback_config(listen=[endpoint])) as session:
        for detector in detectors:
            camera = Camera(True)
            with services((detector,), endpoint, session, flags=flags) as remotes:
                remote = remotes[detector]
                remote.warm_up(width, height, camera)
                remote.clear_records()
                count = int(seconds * hz)
                period = 1.0 / hz
                begin = time.perf_counter()
                for index in range(count):
                    frame = raw_frame(images[index % len(images)], index)
                    remote.publisher.put(camera.load(frame.payload), attachment=frame.attachment)
                    next_at = begin + (index + 1) * period
                    while (left := next_at - time.perf_counter()) > 0:
                        time.sleep(left)
                time.sleep(1.0)  # the last answers
                answered = remote.tags.qsize()
                records = remote.records()
            frame_ms = [
                r["timing"]["decode_ms"] + r["timing"]["convert_ms"] + r["timing"]["detect_ms"]
                for r in records
            ]
            detect = _median([r["timing"]["detect_ms"] for r in records])
            out[detector] = {
                "put": count,
                "answered": answered,
                "answered_hz": round(answered / seconds, 1),
                "detect_median_ms": round(detect, 3),
                "frame_median_ms": round(_median(frame_ms), 3),
                "max_hz_from_frame_ms": round(1e3 / _median(frame_ms), 1) if frame_ms else None,
            }
    return out


def report(rows: list[dict[str, Any]], rate: dict[str, dict[str, Any]] | None, hz: float) -> str:
    lines = [
        "lockstep, same frames, one run; ms are medians; +bare = path minus OpenCV bare; "
        "own = service tag (record) - floor - bare; peer = the floor reading with OpenCV in its "
        "callback; vs peer = service tag (record) - peer's",
        f"{'frames':<18}{'camera':<7}{'bare':>7}{'floor':>7}{'tag':>7}{'record':>8}"
        f"{'+bare tag':>10}{'+bare rec':>10}{'x bare':>7}{'own':>7}{'own rec':>8}"
        f"{'peer':>7}{'vs peer':>8}{'vs peer rec':>12}",
    ]
    for r in rows:
        goal = ""
        if r["resolution"].startswith("HD720"):
            met = (
                r["vs_peer_ms"] <= OWN_TAG_GOAL_MS and r["vs_peer_record_ms"] <= OWN_RECORD_GOAL_MS
            )
            goal = (
                f"  goal <= {OWN_TAG_GOAL_MS} / {OWN_RECORD_GOAL_MS}: {'met' if met else 'MISSED'}"
            )
        lines.append(
            f"{r['resolution']:<18}{r['camera']:<7}{r['bare_ms']:>7.2f}{r['floor_ms']:>7.2f}"
            f"{r['tag_ms']:>7.2f}{r['record_ms']:>8.2f}{r['tag_over_bare_ms']:>10.2f}"
            f"{r['record_over_bare_ms']:>10.2f}{r['tag_ratio']:>7.2f}{r['own_ms']:>7.2f}"
            f"{r['own_record_ms']:>8.2f}{r['peer_ms']:>7.2f}{r['vs_peer_ms']:>8.2f}"
            f"{r['vs_peer_record_ms']:>12.2f}{goal}"
        )
    if rate:
        lines.append(f"HD1080 at {hz:g} Hz (shared memory):")
        for name, r in rate.items():
            lines.append(
                f"  {name:<10} answered {r['answered']}/{r['put']} ({r['answered_hz']} Hz); "
                f"decode+convert+detect median {r['frame_median_ms']} ms "
                f"(detect {r['detect_median_ms']} ms) -> at most {r['max_hz_from_frame_ms']} Hz"
            )
    lines.append(f"load average {os.getloadavg()[0]:.1f}")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    count = args.frames or (4 if args.quick else 20)
    seed = args.seed if args.seed is not None else 2024
    frames = {name: frames_at(name, count, seed + i) for i, name in enumerate(RESOLUTIONS)}
    frames[LOOKALIKES] = frames_at("HD720", count, seed + len(frames), lookalikes=True)
    progress = Progress(count * len(frames))
    flags = ("-s", str(args.settings)) if args.settings is not None else ()
    deadline = ("--frame-deadline-ms", str(LOCKSTEP_DEADLINE_MS))
    rows = overhead_rows(lockstep_sizes(frames, progress, (*flags, *deadline)))
    rate = None
    if args.rate:
        seconds = 2.0 if args.quick else 8.0
        rate = paced(E2E_DETECTORS, frames["HD1080"], args.rate, seconds, flags)
    print(report(rows, rate, args.rate or 0.0))
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": rows, "rate": rate}, indent=2))
    return 0 if rows else 1
