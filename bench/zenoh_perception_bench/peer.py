"""``bench --peer ros2``: this service against the ROS 2 node users would otherwise run.

On the same HD720 frames (1-4 tags each), in one run, each frame goes in lockstep (the next
one is sent once the previous one is answered), the order rotating per frame, to:

- OpenCV's default, bare, in the bench's process
  (:class:`~zenoh_perception_bench.runners.Baseline`);
- the transport floor and ``zenoh-perception run`` (OpenCV's detector), end to end through
  Zenoh (:mod:`~zenoh_perception_bench.processes`; put -> ``tag``);
- a ros2_aruco-style rclpy node (:mod:`~zenoh_perception_bench.ros2_peer`) over Fast DDS, its
  images reliable, then best effort (``qos_profile_sensor_data``); publish -> answer, timed
  in its ROS 2 camera process, which the bench drives one frame at a time over a pipe.

The ROS 2 side runs in a Python with the ``ros2`` extra (``pip install -e '.[ros2]'``;
``--ros-python`` another one), on a private ``ROS_DOMAIN_ID``, discovery limited to localhost.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, TextIO

import numpy as np
import numpy.typing as npt
import zenoh

import zenoh_perception
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import (
    FLOOR,
    Camera,
    ServiceError,
    raw_frame,
    services,
    stop_service,
)
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.runners import DICTIONARY, Baseline, rotation
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator

Image = npt.NDArray[np.uint8]

#: What ``--peer ros2`` needs importable in the ROS 2 Python.
ROS2_MODULES: Final = ("rclpy", "sensor_msgs.msg", "geometry_msgs.msg", "rmw_fastrtps_cpp")
MISSING_ROS2: Final = (
    "error: bench --peer ros2 needs ROS 2 Jazzy's Python packages: pip install -e '.[ros2]'"
)
BARE: Final = "opencv bare"
SERVICE: Final = "opencv"  # the service's detector measured end to end
ROS2_QOS: Final = ("reliable", "best_effort")
RESOLUTION: Final = "HD720"


def ros2_available(python: str) -> bool:
    """Whether ``python`` imports the ROS 2 packages the peer needs."""
    code = "import " + ", ".join(ROS2_MODULES)
    try:
        done = subprocess.run([python, "-c", code], capture_output=True, check=False)
    except OSError:  # no such interpreter
        return False
    return done.returncode == 0


def ros2_env() -> dict[str, str]:
    """Fast DDS, a private domain, localhost discovery; this package importable."""
    root = str(Path(zenoh_perception.__file__).resolve().parents[1])
    path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
    return dict(
        os.environ,
        RMW_IMPLEMENTATION="rmw_fastrtps_cpp",
        ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", str(random.randint(40, 99))),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONPATH=path,
        PYTHONUNBUFFERED="1",
    )


class RosCamera:
    """The ROS 2 camera process (``ros2_peer camera``), driven one frame at a time."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc

    def _line(self) -> str:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            msg = f"the ROS 2 camera exited with {self.proc.wait()}"
            raise ServiceError(msg)
        return line.strip()

    def wait_ready(self) -> None:
        line = self._line()
        if line != "ready":
            raise ServiceError(f"the ROS 2 camera: {line}")

    def send(self, qos: str, index: int) -> float | None:
        """Milliseconds from publish to answer (None: lost)."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{qos} {index}\n")
        self.proc.stdin.flush()
        line = self._line()
        return None if line == "lost" else float(line)


@contextmanager
def ros2_peers(python: str, frames: Path, dictionary: str, log: TextIO) -> Iterator[RosCamera]:
    """One node per QoS and the camera, always stopped on exit."""
    env = ros2_env()
    tag = f"zp_bench_{os.getpid()}"
    module = [python, "-m", "zenoh_perception_bench.ros2_peer"]
    procs: list[subprocess.Popen[Any]] = []
    try:
        routes = []
        for qos in ROS2_QOS:
            image, answer = f"/{tag}/{qos}/image", f"/{tag}/{qos}/markers"
            routes += ["--route", f"{qos}:{image}:{answer}"]
            node = [*module, "node", "--qos", qos, "--input", image, "--output", answer]
            procs.append(
                subprocess.Popen(
                    [*node, "--dictionary", dictionary], env=env, stdout=log, stderr=log
                )
            )
        camera = subprocess.Popen(
            [*module, "camera", "--frames", str(frames), *routes],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
        )
        procs.append(camera)
        ros = RosCamera(camera)
        ros.wait_ready()
        yield ros
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                stop_service(proc)


@dataclass(slots=True)
class PeerRun:
    """Milliseconds per frame and path (None: the frame was lost)."""

    times: dict[str, list[float | None]] = field(default_factory=dict)
    camera: dict[str, Any] = field(default_factory=dict)
    frames: int = 0


def peer_frames(count: int, seed: int) -> list[Image]:
    """HD720 BGRA frames, 1-4 tags and realistic effects each."""
    scenes = SceneGenerator(CameraModel.named(RESOLUTION), seed=seed, effects=Effects.realistic())
    return [scenes.random_scene(1 + index % 4, 0).image for index in range(count)]


def run_peer(
    images: Sequence[Image],
    python: str,
    progress: Progress | None,
    *,
    dictionary: str = DICTIONARY,
    shm: bool = True,
) -> PeerRun:
    """Every frame through every path, in lockstep, the order rotating per frame."""
    ros_steps = [f"ros2 {qos}" for qos in ROS2_QOS]
    run = PeerRun({name: [] for name in (BARE, FLOOR, SERVICE, *ros_steps)}, frames=len(images))
    baseline = Baseline(dictionary)
    camera = Camera(shm)
    bench_endpoint = loopback_endpoint()
    height, width = images[0].shape[:2]
    with ExitStack() as stack:
        tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="zp-peer-")))
        np.save(tmp / "frames.npy", np.stack(images))
        log = stack.enter_context((tmp / "ros2.log").open("w+", encoding="utf-8"))
        try:
            ros = stack.enter_context(ros2_peers(python, tmp / "frames.npy", dictionary, log))
        except ServiceError as err:
            log.seek(0)
            raise ServiceError(f"{err}; its output:\n{log.read()[-4000:]}") from err
        session = stack.enter_context(zenoh.open(loopback_config(listen=[bench_endpoint])))
        remotes = stack.enter_context(services((FLOOR, SERVICE), bench_endpoint, session))
        for remote in remotes.values():
            remote.warm_up(width, height, camera)
        for index, image in enumerate(images):
            frame = raw_frame(image, index)
            for step in rotation(list(run.times), index):
                if step == BARE:
                    run.times[step].append(baseline.run(image)[1])
                elif step in remotes:
                    remote = remotes[step]
                    loaded = camera.load(frame.payload)
                    start = time.perf_counter()
                    remote.publisher.put(loaded, attachment=frame.attachment)
                    run.times[step].append((remote.wait_answer() - start) * 1e3)
                    del loaded
                else:
                    run.times[step].append(ros.send(step.removeprefix("ros2 "), index))
            tick(progress, "peer ros2")
    run.camera = camera.summary()
    return run


def summary(run: PeerRun) -> list[dict[str, Any]]:
    """Per path: answered frames, median and p90 ms, and the median's excess over bare
    OpenCV (ms and ratio) and over the floor."""
    bare = float(np.median(np.asarray(run.times[BARE], dtype=np.float64)))
    floor_times = [t for t in run.times[FLOOR] if t is not None]
    floor = float(np.median(np.asarray(floor_times))) if floor_times else float("nan")
    rows = []
    for name, times in run.times.items():
        kept = np.asarray([t for t in times if t is not None], dtype=np.float64)
        median = float(np.median(kept)) if kept.size else float("nan")
        rows.append(
            {
                "path": name,
                "answered": int(kept.size),
                "frames": run.frames,
                "median_ms": round(median, 3),
                "p90_ms": round(float(np.percentile(kept, 90)), 3) if kept.size else None,
                "over_bare_ms": round(median - bare, 3),
                "ratio_to_bare": round(median / bare, 2),
                "over_floor_ms": round(median - floor, 3),
            }
        )
    return rows


def report(run: PeerRun) -> str:
    head = (
        f"{'path':<22}{'answered':>10}{'median ms':>11}{'p90 ms':>9}"
        f"{'+bare ms':>10}{'x bare':>8}{'+floor ms':>11}"
    )
    lines = [f"HD720, {run.frames} frames, lockstep, same frames, one run", head]
    for row in summary(run):
        p90 = "-" if row["p90_ms"] is None else f"{row['p90_ms']:.2f}"
        lines.append(
            f"{row['path']:<22}{row['answered']:>5}/{row['frames']:<4}"
            f"{row['median_ms']:>11.2f}{p90:>9}{row['over_bare_ms']:>10.2f}"
            f"{row['ratio_to_bare']:>8.2f}{row['over_floor_ms']:>11.2f}"
        )
    camera = "shared memory" if run.camera.get("shm") else "plain bytes"
    lines.append(f"zenoh camera: {camera}; load average {os.getloadavg()[0]:.1f}")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    """``bench --peer ros2``: exit 2 when the ROS 2 packages are missing."""
    python = args.ros_python or sys.executable
    if not ros2_available(python):
        print(MISSING_ROS2, file=sys.stderr)
        return 2
    count = args.frames or (12 if args.quick else 85)
    images = peer_frames(count, args.seed if args.seed is not None else 2024)
    progress = Progress(count)
    run = run_peer(images, python, progress, shm=not args.no_shm)
    print(report(run))
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": summary(run), "camera": run.camera}, indent=2))
    return 0
