"""Frames that stall OpenCV's detector, and what the frame deadline costs.

``python -m tools.stalls [--frames N] [--json PATH]`` measures, on this machine and in one
run:

1. OpenCV's default ``ArucoDetector`` alone on checkerboards whose squares sit just above its
   smallest marker (HD720 / 10 px, HD1080 / 15 px, 4096 x 4096 / 32 px) and on generated HD720
   scenes;
2. what the child process costs a normal frame (the same detector here and there, alternately),
   and the alternatives to it, in this process: a second thread reading a normal
   frame while a board stalls the first; a pre-check (adaptive threshold and contour count on
   a half-size image), its cost and its counts; OpenCV parameters that bound the work, the
   board's time with them and what they change on normal frames;
3. two service processes, ``frame_deadline_ms`` 400 (the default) and 0 (off), in lockstep on
   the same generated HD720 frames, the order rotating per frame: put -> ``tag`` times;
4. through both services, a board then a normal frame: put of the normal frame -> its tag, the
   board's fate (abandoned, or answered late); SIGTERM during a 4096 x 4096 board: seconds to
   exit.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import zenoh

from tools.rig import percentile
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.service.child_detector import IsolatedDetector
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import (
    Camera,
    RawFrame,
    Remote,
    ServiceProcess,
    raw_frame,
    stop_service,
)
from zenoh_perception_bench.runners import DICTIONARY, rotation
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator

Gray = npt.NDArray[np.uint8]
#: (width, height, square px): the boards of the measurements.
BOARDS = ((1280, 720, 10), (1920, 1080, 15), (4096, 4096, 32))
DEADLINE_MS = 400.0


def checkerboard(width: int, height: int, square: int) -> Gray:
    """Black and white squares of ``square`` px."""
    y, x = np.indices((height, width))
    return np.asarray(((x // square + y // square) % 2) * 255, dtype=np.uint8)


def hd720_scenes(count: int, seed: int = 2024) -> list[npt.NDArray[np.uint8]]:
    """Generated HD720 BGRA scenes, 4 tags and 2 look-alikes each (the bench's HD720 set)."""
    scenes = SceneGenerator(CameraModel.named("HD720"), seed=seed, effects=Effects.realistic())
    return [scenes.random_scene(4, 2).image for _ in range(count)]


def _gray(bgra: npt.NDArray[np.uint8]) -> Gray:
    return np.asarray(cv2.cvtColor(bgra, cv2.COLOR_BGRA2GRAY), np.uint8)


def _detector(params: Any = None) -> Any:
    if params is None:
        params = cv2.aruco.DetectorParameters()
    return cv2.aruco.ArucoDetector(aruco_dictionary(DICTIONARY), params)


def _ms(run: Callable[..., object], *args: object) -> float:
    """Milliseconds ``run(*args)`` takes."""
    start = time.perf_counter()
    run(*args)
    return (time.perf_counter() - start) * 1e3


def _median_ms(run: Callable[[Gray], object], images: Sequence[Gray]) -> float:
    return float(np.median([_ms(run, image) for image in images]))


def opencv_alone(normal: Sequence[Gray]) -> dict[str, Any]:
    detector = _detector()
    boards = {
        f"{w}x{h}/{s}px": _ms(detector.detectMarkers, checkerboard(w, h, s)) for w, h, s in BOARDS
    }
    return {
        "board_ms": boards,
        "normal_hd720_median_ms": _median_ms(detector.detectMarkers, normal),
    }


def second_thread(normal: Sequence[Gray]) -> dict[str, Any]:
    """A normal frame's time while another thread is stuck on the HD720 board."""
    alone = _median_ms(_detector().detectMarkers, normal)
    board = checkerboard(1280, 720, 10)
    stuck = threading.Thread(target=lambda: _detector().detectMarkers(board), daemon=True)
    other = _detector()
    times: list[float] = []
    started = time.perf_counter()
    stuck.start()
    while stuck.is_alive():
        times += [_ms(other.detectMarkers, image) for image in normal]
    return {
        "normal_alone_median_ms": alone,
        "normal_beside_board_median_ms": float(np.median(times)) if times else None,
        "board_beside_normal_ms": (time.perf_counter() - started) * 1e3,
    }


def _contours(gray: Gray) -> int:
    small = cv2.resize(gray, (gray.shape[1] // 2, gray.shape[0] // 2), interpolation=cv2.INTER_AREA)
    binary = cv2.adaptiveThreshold(
        small, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, 7, 7
    )
    contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return len(contours)


def pre_check(normal: Sequence[Gray]) -> dict[str, Any]:
    clutter = np.repeat(
        np.repeat(np.random.default_rng(0).integers(0, 256, (90, 160), dtype=np.uint8), 8, 0), 8, 1
    )
    detector = _detector()
    return {
        "normal_hd720_median_ms": _median_ms(_contours, normal),
        "normal_hd720_contours_max": max(_contours(g) for g in normal),
        "boards": {
            f"{w}x{h}/{s}px": {
                "ms": _ms(_contours, checkerboard(w, h, s)),
                "contours": _contours(checkerboard(w, h, s)),
            }
            for w, h, s in BOARDS
        },
        "hd720_8px_random_blocks": {
            "contours": _contours(clutter),
            "opencv_ms": _ms(detector.detectMarkers, clutter),
        },
    }


def bounded_parameters(normal: Sequence[Gray]) -> dict[str, Any]:
    """The HD720 board's time and the tags found on the normal frames with parameters that
    cut OpenCV's work, against the defaults."""
    variants: dict[str, dict[str, float]] = {
        "default": {},
        "minMarkerPerimeterRate x2": {"minMarkerPerimeterRate": 0.06},
        "one threshold window": {"adaptiveThreshWinSizeMax": 3},
    }
    out: dict[str, Any] = {}
    board = checkerboard(1280, 720, 10)
    for name, values in variants.items():
        params = cv2.aruco.DetectorParameters()
        for key, value in values.items():
            setattr(params, key, value)
        detector = _detector(params)
        found = sum(len(detector.detectMarkers(g)[0]) for g in normal)
        out[name] = {
            "board_hd720_ms": _ms(detector.detectMarkers, board),
            "tags_found": found,
        }
    return out


def child_process(normal: Sequence[Gray], passes: int = 3) -> dict[str, Any]:
    """The same detector in this process and in the deadline's child process, alternately on
    the same frames: what the child costs per frame (the hop, not the detection)."""
    local = make_detector("opencv", DICTIONARY)
    factory = partial(make_detector, "opencv", DICTIONARY)
    here: list[float] = []
    there: list[float] = []
    with IsolatedDetector(factory, 10.0) as isolated:
        isolated.detect(normal[0])  # the child's detector built
        for _ in range(passes):
            for image in normal:
                here.append(_ms(local.detect, image))
                there.append(_ms(isolated.detect, image))
    extra = np.subtract(there, here)
    return {
        "in_process_median_ms": float(np.median(here)),
        "child_median_ms": float(np.median(there)),
        "extra_median_ms": float(np.median(extra)),
        "extra_mean_ms": float(np.mean(extra)),
    }


# -- through service processes ---------------------------------------------------------------


def _board_frame(width: int, height: int, square: int, seq: int) -> RawFrame:
    meta = RawFrameMeta(width, height, "mono8", seq=seq, frame_id="bench")
    return RawFrame(checkerboard(width, height, square).tobytes(), meta.to_msgpack())


def _received(remote: Remote) -> int:
    return int(remote.status()["frames"]["received"])


def _put_and_wait_received(remote: Remote, frame: RawFrame) -> None:
    before = _received(remote)
    remote.publisher.put(frame.payload, attachment=frame.attachment)
    deadline = time.monotonic() + 30.0
    while _received(remote) == before and time.monotonic() < deadline:
        pass


def services(frames: int) -> dict[str, Any]:
    images = hd720_scenes(frames, seed=7)
    camera = Camera(shm=True)
    endpoint = loopback_endpoint()
    flags = {
        "deadline": ("--frame-deadline-ms", str(DEADLINE_MS)),
        "off": ("--frame-deadline-ms", "0"),
    }
    out: dict[str, Any] = {}
    with zenoh.open(loopback_config(listen=[endpoint])) as session:
        processes = {n: ServiceProcess(n, "opencv", endpoint, extra=f) for n, f in flags.items()}
        remotes = {n: Remote(session, p) for n, p in processes.items()}
        try:
            for remote in remotes.values():
                remote.wait_ready()
                remote.warm_up(1280, 720, camera)
            latencies: dict[str, list[float]] = {n: [] for n in remotes}
            for index, image in enumerate(images):
                frame = raw_frame(image, index)
                for name in rotation(list(remotes), index):
                    loaded = camera.load(frame.payload)
                    start = time.perf_counter()
                    remotes[name].publisher.put(loaded, attachment=frame.attachment)
                    latencies[name].append((remotes[name].wait_answer() - start) * 1e3)
                    del loaded
            out["lockstep_hd720"] = {
                n: {
                    "median_ms": float(np.median(v)),
                    "mean_ms": float(np.mean(v)),
                    "p90_ms": percentile(v, 90),
                }
                for n, v in latencies.items()
            }
            good = raw_frame(images[0], 10_000)
            stalls: dict[str, Any] = {}
            for width, height, square in BOARDS:
                label = f"{width}x{height}/{square}px"
                stalls[label] = {}
                for name, remote in remotes.items():
                    remote.drain()
                    _put_and_wait_received(remote, _board_frame(width, height, square, 20_000))
                    start = time.perf_counter()
                    remote.publisher.put(good.payload, attachment=good.attachment)
                    answers = [remote.wait_answer(120.0)]
                    if name == "off":  # the board's late answer comes first
                        answers.append(remote.wait_answer(120.0))
                    status = remote.status()
                    stalls[label][name] = {
                        "good_frame_answer_ms": (answers[-1] - start) * 1e3,
                        "tags_for_two_frames": len(answers),
                        "abandoned": status["budget"]["abandoned"],
                        "abandoned_ms_last": status["budget"]["abandoned_ms_last"],
                    }
            out["stalls"] = stalls
            exits: dict[str, float] = {}
            for name, remote in remotes.items():
                _put_and_wait_received(remote, _board_frame(4096, 4096, 32, 30_000))
                remote.close()
                code, seconds = stop_service(processes[name].proc)
                exits[name] = seconds
                out.setdefault("sigterm_exit_code", {})[name] = code
            out["sigterm_during_4096_board_s"] = exits
        finally:
            for remote in remotes.values():
                remote.close()
            for process in processes.values():
                process.stop()
    return out


def main(frames: int = 60, *, json_path: Path | None = None, with_services: bool = True) -> int:
    """Measure, print the figures as JSON (also to ``json_path``)."""
    normal = [_gray(image) for image in hd720_scenes(min(frames, 20))]
    report: dict[str, Any] = {
        "opencv_alone": opencv_alone(normal),
        "second_thread": second_thread(normal),
        "pre_check": pre_check(normal),
        "bounded_parameters": bounded_parameters(normal),
        "child_process": child_process(normal),
    }
    if with_services:
        report["services"] = services(frames)
    text = json.dumps(report, indent=2, default=lambda v: round(float(v), 2))
    print(text)
    if json_path is not None:
        json_path.write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        prog="python -m tools.stalls", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--frames", type=int, default=60, help="generated HD720 frames")
    parser.add_argument("--json", type=Path, help="write the figures here too")
    parser.add_argument("--no-services", action="store_true", help="OpenCV in process only")
    args = parser.parse_args()
    sys.exit(main(args.frames, json_path=args.json, with_services=not args.no_services))
