"""``zenoh-perception bench --fleet``: cameras, routers and instances of a share group, each a
process of its own, on this machine.

Topology (every process on loopback, multicast scouting off)::

    cameras (N processes) --client--> router A <--- router B <--client-- instances (M)
                                                       ^
                                                       +--client-- this bench (records)

Shared memory is off in every process: frames cross the links as bytes, as they would between
machines. ``--fleet-shm`` turns it on everywhere (the cameras put from shared memory): the
capacity of the instances themselves, without the copies of the transport.

Router A stands for the rover (the cameras' side), router B for the base station (the
instances' side): frames cross the A-B link only for the streams some instance holds.

For each (N, M):

1. **Hand-over.** N cameras put VGA frames at ``--fleet-rate`` Hz each (plain bytes,
   congestion control BLOCK: Zenoh drops none). Measured over a steady window: frames
   answered, duplicates, unanswered frames, and the bytes each instance process read
   (its TCP sockets' ``bytes_received``, as ``ss`` reports them) against what every camera offers.
   Then one instance is killed (SIGKILL) and one joins (with M = 1 the join comes first):
   after each, the time until every stream is answered again, the frames left unanswered,
   and the duplicates, in all and after the hand-over (frames stamped 3 s after the event).
2. **Capacity.** The cameras put HD720 frames as fast as ``1.2 x`` the
   limit in total, congestion control DROP; frames answered per second across the streams
   over a window, and per-stream latency (camera stamp to the record's arrival here), set
   against the limit: bare OpenCV's default (grey conversion and ``detectMarkers``) reading
   the same frame in a loop in this process, measured in the same run before and after.
   On one machine the cameras and routers take cores from the instances, so the CPU-seconds
   each kind of process used in the window are measured too, and the instances' frames per
   CPU-second are set against bare OpenCV's: what an instance makes of the cores it gets.

This is a benchmark, not a test: it prints figures, and exit code 1 only when a process
failed. The camera and router processes are this module run as a program
(``python -m zenoh_perception_bench.fleet camera|router ...``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import zenoh

from zenoh_perception.camera.shm import ShmPutter, announce
from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.service.signals import stop_on_signals
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.records import decode_record
from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.scene import CameraModel, SceneGenerator

#: (cameras, instances) of a full run.
CONFIGS: Final = ((1, 1), (4, 1), (4, 2), (8, 3))
GROUP: Final = "fleet"
INPUT: Final = "fleet/*/image"
RECORDS: Final = "fleet/*/perception/tags"
#: Each stream's outputs: ``{stream}`` is the chunk of the camera's key that ``*`` matched.
OUTPUTS: Final = (
    ("--tag-key", "fleet/{stream}/tag"),
    ("--record-key", "fleet/{stream}/perception/tags"),
    ("--debug-image-key", "fleet/{stream}/perception/debug"),
    ("--detections-key", "fleet/{stream}/perception/detections"),
)
#: After a kill or a join, frames stamped this long after it must be answered exactly once.
HANDOVER_S: Final = 3.0
#: Offered load of the capacity phase, in multiples of the limit.
OVERLOAD: Final = 1.2
STARTUP_TIMEOUT_S: Final = 120.0
#: Off in every process of the fleet: frames cross the links as bytes, as between machines
#: (on one machine Zenoh would otherwise pass large payloads through shared memory, and the
#: sockets would carry none of them).
SHM_SETTING: Final = "transport/shared_memory/enabled"


# -- child processes ---------------------------------------------------------------------------


def _child(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(prog="fleet")
    parser.add_argument("role", choices=["camera", "router"])
    parser.add_argument("--listen", action="append", default=[])
    parser.add_argument("--connect", action="append", default=[])
    parser.add_argument("--key", default="")
    parser.add_argument("--resolution", default="VGA")
    parser.add_argument("--rate", type=float, default=5.0)
    parser.add_argument("--shm", action="store_true")
    parser.add_argument("--drop", action="store_true")
    args = parser.parse_args(argv)
    stop = stop_on_signals()
    mode = "router" if args.role == "router" else "client"
    conf = loopback_config(mode=mode, listen=args.listen, connect=args.connect)
    if not args.shm:
        conf.insert_json5(SHM_SETTING, "false")
    with zenoh.open(conf) as s:
        if args.role == "router":
            stop.wait()
            return 0
        _camera(s, args, stop)
    return 0


def _camera(session: zenoh.Session, args: argparse.Namespace, stop: threading.Event) -> None:
    """Put one marker frame at ``args.rate`` Hz, each with its stamp, the stream's name as
    frame id and a seq; late frames are not caught up."""
    width, height = RESOLUTIONS[args.resolution]
    frames = scene_frames(args.resolution)
    name = args.key.split("/")[1]
    congestion = zenoh.CongestionControl.DROP if args.drop else zenoh.CongestionControl.BLOCK
    putter = ShmPutter() if args.shm else None
    with (
        session.declare_publisher(args.key, congestion_control=congestion) as publisher,
        announce(session, args.key),
    ):
        period, due, seq = 1.0 / args.rate, time.monotonic(), 0
        while not stop.is_set():
            meta = RawFrameMeta(width, height, stamp_ns=time.time_ns(), frame_id=name, seq=seq)
            pixels = frames[seq % len(frames)]
            payload = pixels if putter is None else putter.load(pixels)
            publisher.put(payload, attachment=meta.to_msgpack())
            seq += 1
            due += period
            delay = due - time.monotonic()
            if delay > 0:
                stop.wait(delay)
            else:
                due = time.monotonic()


def scene_frames(resolution: str, count: int = 4) -> list[bytes]:
    """BGRA frames of a generated drive toward tags (textured ground, posts, look-alikes):
    what every camera of the bench cycles through, and what the limit is measured on."""
    scenes = SceneGenerator(CameraModel.named(resolution), seed=1).drive(
        count, fps=15.0, speed_mps=0.6
    )
    return [scene.image.tobytes() for scene in scenes]


def _module_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "zenoh_perception_bench.fleet", *args]


def _spawn(command: list[str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


# -- the bench side ---------------------------------------------------------------------------


@dataclass(slots=True)
class Answer:
    stream: str
    seq: int
    stamp_ns: int
    received_ns: int  # wall clock here


class Records:
    """Every record the instances publish, as (stream, seq, stamps)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.answers: list[Answer] = []
        self._lock = threading.Lock()
        self._subscriber = session.declare_subscriber(RECORDS, self._on_record)

    def _on_record(self, sample: zenoh.Sample) -> None:
        received = time.time_ns()
        try:
            record = decode_record(sample.payload.to_bytes())
        except MessageDecodeError:
            return
        answer = Answer(str(record["frame_id"]), int(record["seq"]), record["stamp_ns"], received)
        with self._lock:
            self.answers.append(answer)

    def since(self, wall_ns: int) -> list[Answer]:
        """Answers to frames stamped at or after ``wall_ns``."""
        with self._lock:
            return [a for a in self.answers if a.stamp_ns >= wall_ns]

    def close(self) -> None:
        self._subscriber.undeclare()  # type: ignore[no-untyped-call]


@dataclass(slots=True)
class Window:
    """What one stretch of time showed."""

    answered: int = 0
    duplicates: int = 0
    unanswered: int = 0
    late_duplicates: int = 0  # after the hand-over
    late_unanswered: int = 0
    resumed_s: float = 0.0  # longest time a stream went unanswered after the event


def _window(answers: list[Answer], start_ns: int, end_ns: int, event_ns: int | None) -> Window:
    """Count answers of frames stamped in [start, end): per stream the seqs between its first
    and last answered one are expected (a camera numbers its frames without holes)."""
    by_stream: dict[str, list[Answer]] = defaultdict(list)
    for a in answers:
        if start_ns <= a.stamp_ns < end_ns:
            by_stream[a.stream].append(a)
    result = Window()
    settled_ns = None if event_ns is None else event_ns + int(HANDOVER_S * 1e9)
    for stream_answers in by_stream.values():
        seqs: dict[int, list[Answer]] = defaultdict(list)
        for a in stream_answers:
            seqs[a.seq].append(a)
        result.answered += len(seqs)
        for group in seqs.values():
            extra = len(group) - 1
            result.duplicates += extra
            if settled_ns is not None and group[0].stamp_ns >= settled_ns:
                result.late_duplicates += extra
        ordered = sorted(seqs)
        missing = [s for s in range(ordered[0], ordered[-1] + 1) if s not in seqs]
        result.unanswered += len(missing)
        if settled_ns is not None and event_ns is not None:
            first_late = min(
                (s for s in ordered if seqs[s][0].stamp_ns >= settled_ns), default=None
            )
            if first_late is not None:
                result.late_unanswered += sum(1 for s in missing if s > first_late)
            stamps = sorted(seqs[s][0].stamp_ns for s in ordered)
            gaps = [
                (b - max(a, event_ns)) / 1e9 for a, b in itertools.pairwise(stamps) if b > event_ns
            ]
            result.resumed_s = max([result.resumed_s, *gaps])
    return result


def bytes_received(pids: Sequence[int]) -> dict[int, int]:
    """Bytes each process's established TCP sockets have received so far (``ss``'s
    ``bytes_received``, from the kernel's tcp_info); 0 for a process without one."""
    totals = dict.fromkeys(pids, 0)
    try:
        out = subprocess.run(
            ["ss", "-Htinp", "state", "established"],
            capture_output=True,
            text=True,
            check=False,
            timeout=10,
        ).stdout
    except (OSError, subprocess.TimeoutExpired):
        return totals
    owner: int | None = None
    for line in out.splitlines():
        found = _PID.search(line)
        if found is not None:
            owner = int(found.group(1))
            continue
        got = _BYTES_RECEIVED.search(line)
        if got is not None and owner in totals:
            totals[owner] += int(got.group(1))
            owner = None
    return totals


_PID: Final = re.compile(r"pid=(\d+),")
_BYTES_RECEIVED: Final = re.compile(r"bytes_received:(\d+)")


@dataclass(frozen=True, slots=True)
class Limit:
    """Bare OpenCV's default reading the bench's frames in a loop: frames per second, and
    frames per CPU-second of this process (OpenCV's own threads included)."""

    fps: float
    per_cpu_s: float


def cpu_seconds(pids: Sequence[int]) -> dict[int, float]:
    """CPU seconds (user and system, every thread) each of ``pids`` has used so far; a
    process that is gone counts 0."""
    tick = os.sysconf("SC_CLK_TCK")
    used = {}
    for pid in pids:
        try:
            text = Path(f"/proc/{pid}/stat").read_text(encoding="ascii")
        except OSError:
            used[pid] = 0.0
            continue
        fields = text.rsplit(")", 1)[1].split()  # after the command name
        used[pid] = (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return used


def opencv_limit(resolution: str, seconds: float) -> Limit:
    """Bare OpenCV's default reading the bench's frames in a loop (see :class:`Limit`)."""
    width, height = RESOLUTIONS[resolution]
    images = [
        np.frombuffer(f, dtype=np.uint8).reshape(height, width, 4) for f in scene_frames(resolution)
    ]
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    count, start, cpu = 0, time.perf_counter(), time.process_time()
    while (elapsed := time.perf_counter() - start) < seconds or count < 3:
        detector.detectMarkers(cv2.cvtColor(images[count % len(images)], cv2.COLOR_BGRA2GRAY))
        count += 1
    return Limit(count / elapsed, count / max(time.process_time() - cpu, 1e-9))


@dataclass(slots=True)
class Fleet:
    """The processes of one (N, M) run."""

    router_a: str
    router_b: str
    router_pids: tuple[int, ...] = ()
    shm: bool = False  # shared memory on in every process, the cameras' puts from it
    cameras: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)
    instances: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def start_cameras(self, n: int, resolution: str, rate: float, *, drop: bool) -> None:
        for i in range(n):
            key = f"fleet/cam{i}/image"
            args = ["camera", "--connect", self.router_a, "--key", key]
            args += ["--resolution", resolution, "--rate", f"{rate:g}"]
            args += ["--drop"] if drop else []
            args += ["--shm"] if self.shm else []
            self.cameras[key] = _spawn(_module_command(*args))

    def stop_cameras(self) -> None:
        for proc in self.cameras.values():
            _stop(proc)
        self.cameras.clear()

    def start_instance(self) -> subprocess.Popen[bytes]:
        command = [sys.executable, "-m", "zenoh_perception", "run", "-m", "client"]
        command += ["-e", self.router_b, "--no-multicast-scouting", "--share-group", GROUP]
        command += ["--input-key", INPUT, "--compressed-input-key", ""]
        command += ["--stats-interval-s", "0"]
        command += [word for flag in OUTPUTS for word in flag]
        command += [] if self.shm else ["--cfg", f"{SHM_SETTING}:false"]
        proc = _spawn(command)
        self.instances.append(proc)
        return proc

    def close(self) -> None:
        self.stop_cameras()
        for proc in self.instances:
            _stop(proc)


def _statuses(session: zenoh.Session) -> list[dict[str, Any]]:
    replies = session.get(
        "perception/status",
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=1.0,
    )
    return [json.loads(r.ok.payload.to_string()) for r in replies if r.ok is not None]


def _wait(condition: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    pause = threading.Event()
    while not condition():
        if time.monotonic() > deadline:
            msg = f"fleet: {what} not reached within {timeout:g} s"
            raise TimeoutError(msg)
        pause.wait(0.1)


def _settled(session: zenoh.Session, instances: int, streams: int) -> bool:
    groups = [s.get("group") for s in _statuses(session)]
    if len(groups) != instances or None in groups:
        return False
    held = [len(g["held"]) for g in groups if g is not None]
    return sum(held) == streams and all(
        len(g["members"]) == instances for g in groups if g is not None
    )


@dataclass(slots=True)
class Result:
    n: int
    m: int
    steady: Window
    bytes_per_instance: list[float]  # MB/s each instance read
    offered_mb_s: float
    events: list[tuple[str, Window]]
    capacity_fps: float = 0.0
    #: CPU-seconds a second each kind of process used during the capacity window (2 = both
    #: cores of a 2-core machine): "cameras", "routers", "instances", "bench" (this one).
    cpu_share: dict[str, float] = field(default_factory=dict)
    #: Frames answered per CPU-second of the instances during the capacity window.
    per_cpu_s: float = 0.0
    latency_ms: dict[str, tuple[float, float]] = field(default_factory=dict)
    steady_latency_ms: dict[str, tuple[float, float]] = field(default_factory=dict)
    dropped: int = 0


def run_config(
    session: zenoh.Session,
    fleet: Fleet,
    n: int,
    m: int,
    *,
    rate: float,
    limit: Limit,
    window_s: float,
) -> Result:
    records = Records(session)
    pause = threading.Event()
    try:
        for _ in range(m):
            fleet.start_instance()
        fleet.start_cameras(n, "VGA", rate, drop=False)
        _wait(lambda: _settled(session, m, n), STARTUP_TIMEOUT_S, f"{n} streams over {m}")
        _wait(
            lambda: len({a.stream for a in records.since(time.time_ns() - int(2e9))}) == n,
            STARTUP_TIMEOUT_S,
            "every stream answered",
        )
        # steady window
        start_ns = time.time_ns()
        pids = [p.pid for p in fleet.instances]
        before = bytes_received(pids)
        pause.wait(window_s)
        after = bytes_received(pids)
        end_ns = time.time_ns()
        pause.wait(1.0)  # the window's last answers
        steady = _window(records.answers, start_ns, end_ns, None)
        steady_latency = _latency([a for a in records.answers if start_ns <= a.stamp_ns < end_ns])
        seconds = (end_ns - start_ns) / 1e9
        per_instance = [(after[pid] - before[pid]) / seconds / 1e6 for pid in before]
        width, height = RESOLUTIONS["VGA"]
        offered = n * rate * width * height * 4 / 1e6
        events: list[tuple[str, Window]] = []
        order = ("join", "kill") if m == 1 else ("kill", "join")
        for event in order:
            event_ns = time.time_ns()
            if event == "kill":
                victim = fleet.instances.pop(0)
                victim.kill()
                victim.wait()
            else:
                fleet.start_instance()
            members = len(fleet.instances)
            _wait(lambda k=members: _settled(session, k, n), STARTUP_TIMEOUT_S, f"{event} settled")
            pause.wait(HANDOVER_S + window_s)
            end_ns = time.time_ns()
            pause.wait(1.0)
            events.append((event, _window(records.answers, event_ns, end_ns, event_ns)))
        fleet.stop_cameras()
        # capacity: HD720 from shared memory, offered faster than the limit
        members = len(fleet.instances)
        per_stream = OVERLOAD * limit.fps / n
        fleet.start_cameras(n, "HD720", per_stream, drop=True)
        _wait(lambda: _settled(session, members, n), STARTUP_TIMEOUT_S, "HD720 streams held")
        pause.wait(3.0)  # warm
        start_ns = time.time_ns()
        dropped_before = sum(s["frames"]["dropped"] for s in _statuses(session))
        groups = {
            "cameras": [p.pid for p in fleet.cameras.values()],
            "routers": list(fleet.router_pids),
            "instances": [p.pid for p in fleet.instances],
            "bench": [os.getpid()],
        }
        cpu_before = {k: cpu_seconds(v) for k, v in groups.items()}
        pause.wait(window_s * 2)
        end_ns = time.time_ns()
        cpu_after = {k: cpu_seconds(v) for k, v in groups.items()}
        dropped = sum(s["frames"]["dropped"] for s in _statuses(session)) - dropped_before
        pause.wait(1.0)
        window = [a for a in records.answers if start_ns <= a.stamp_ns < end_ns]
        unique = {(a.stream, a.seq) for a in window}
        result = Result(n, m, steady, per_instance, offered, events)
        seconds = (end_ns - start_ns) / 1e9
        result.capacity_fps = len(unique) / seconds
        used = {k: sum(cpu_after[k][p] - cpu_before[k][p] for p in v) for k, v in groups.items()}
        result.cpu_share = {k: v / seconds for k, v in used.items()}
        result.per_cpu_s = len(unique) / max(used["instances"], 1e-9)
        result.latency_ms = _latency(window)
        result.steady_latency_ms = steady_latency
        result.dropped = dropped
        return result
    finally:
        records.close()
        fleet.close()


def _latency(answers: list[Answer]) -> dict[str, tuple[float, float]]:
    """Median and p95 of camera stamp to record here, ms, per stream."""
    latency: dict[str, list[float]] = defaultdict(list)
    for a in answers:
        latency[a.stream].append((a.received_ns - a.stamp_ns) / 1e6)
    return {
        s: (statistics.median(v), float(np.percentile(np.asarray(v, dtype=np.float64), 95)))
        for s, v in sorted(latency.items())
    }


def ceiling(limit: Limit, cpu_share: dict[str, float], cores: int) -> float:
    """The most frames a second the instances could answer on this machine: bare OpenCV's
    frames per CPU-second on the cores every other process of the run (cameras, routers, the
    bench) left them, and never more than the limit itself (OpenCV's loop alone on every
    core)."""
    others = sum(v for k, v in cpu_share.items() if k != "instances")
    return min(limit.fps, limit.per_cpu_s * max(cores - others, 0.0))


def format_result(r: Result, limit: Limit) -> list[str]:
    s = r.steady
    lines = [
        f"N={r.n} cameras, M={r.m} instances",
        f"  steady (VGA):   {s.answered} frames answered, {s.duplicates} duplicates, "
        f"{s.unanswered} unanswered",
        "  bytes read per instance: "
        + ", ".join(f"{mb:.1f} MB/s" for mb in r.bytes_per_instance)
        + f" (all cameras offer {r.offered_mb_s:.1f} MB/s)",
    ]
    for name, w in r.events:
        lines.append(
            f"  {name:5s} one:       streams answered again after {w.resumed_s:.2f} s; "
            f"{w.unanswered} unanswered, {w.duplicates} duplicates; after the hand-over "
            f"(+{HANDOVER_S:g} s): {w.late_unanswered} unanswered, {w.late_duplicates} "
            f"duplicates ({w.answered} answered)"
        )
    lines.append(
        "  latency per stream (VGA, steady), camera stamp to record here, median / p95 ms: "
        + ", ".join(f"{s} {m:.1f}/{p:.1f}" for s, (m, p) in r.steady_latency_ms.items())
    )
    medians = [v[0] for v in r.latency_ms.values()]
    lines.append(
        f"  capacity (HD720): {r.capacity_fps:.1f} frames/s answered across {r.n} streams, "
        f"limit {limit.fps:.1f}: {r.capacity_fps / limit.fps:.2f}x; {r.dropped} replaced in "
        "mailboxes"
    )
    lines.append(
        "  cores used meanwhile (CPU-s a second): "
        + ", ".join(f"{k} {v:.2f}" for k, v in r.cpu_share.items())
        + f"; the instances answered {r.per_cpu_s:.1f} frames per CPU-second, bare OpenCV "
        f"reads {limit.per_cpu_s:.1f}: {r.per_cpu_s / limit.per_cpu_s:.2f}x"
    )
    top = ceiling(limit, r.cpu_share, os.cpu_count() or 1)
    lines.append(
        f"  ceiling: bare OpenCV's frames per CPU-second on the cores the cameras, routers and "
        f"bench left: {top:.1f} frames/s ({top / limit.fps:.2f}x the limit); the instances "
        f"answered {r.capacity_fps / max(top, 1e-9):.2f}x of it"
    )
    if medians:
        lines.append(
            "  latency per stream (HD720, overloaded: queues), median / p95 ms: "
            + ", ".join(f"{s} {m:.1f}/{p:.1f}" for s, (m, p) in r.latency_ms.items())
        )
    return lines


def _configs(text: str | None) -> list[tuple[int, int]]:
    if not text:
        return list(CONFIGS)
    pairs = []
    for part in text.split(","):
        n, _, m = part.partition("x")
        pairs.append((int(n), int(m)))
    return pairs


@contextmanager
def _routers(*, shm: bool) -> Iterator[tuple[str, str, tuple[int, ...]]]:
    """Routers A and B as processes: their endpoints and process ids."""
    a, b = loopback_endpoint(), loopback_endpoint()
    pids = []
    with ExitStack() as stack:
        for args in (["router", "--listen", a], ["router", "--listen", b, "--connect", a]):
            proc = _spawn(_module_command(*args, *(["--shm"] if shm else [])))
            stack.callback(_stop, proc)
            pids.append(proc.pid)
        yield a, b, tuple(pids)


def _open_when_up(endpoint: str) -> zenoh.Session:
    """A client session of the router at ``endpoint``, once that router process listens."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    pause = threading.Event()
    while True:
        try:
            return zenoh.open(loopback_config(mode="client", connect=[endpoint]))
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            pause.wait(0.2)


def main(args: argparse.Namespace) -> int:
    """Run every (N, M) and print the figures."""
    rate = float(args.fleet_rate)
    window_s = float(args.fleet_window)
    print(f"fleet bench on {os.cpu_count()} cores; load average {os.getloadavg()[0]:.1f}")
    limit_before = opencv_limit("HD720", 5.0)
    print(
        f"limit: bare OpenCV default reads {limit_before.fps:.1f} HD720 frames/s in a loop "
        f"({limit_before.per_cpu_s:.1f} per CPU-second)"
    )
    results = []
    shm = bool(args.fleet_shm)
    if shm:
        print("shared memory on: frames pass as references on this machine (bytes read: ~0)")
    routers = _routers(shm=shm)
    with routers as (router_a, router_b, router_pids), _open_when_up(router_b) as session:
        for n, m in _configs(args.fleet_configs):
            fleet = Fleet(router_a, router_b, router_pids, shm=shm)
            result = run_config(
                session, fleet, n, m, rate=rate, limit=limit_before, window_s=window_s
            )
            results.append(result)
            print("\n".join(format_result(result, limit_before)), flush=True)
    limit_after = opencv_limit("HD720", 5.0)
    print(
        f"limit after the runs: {limit_after.fps:.1f} frames/s, {limit_after.per_cpu_s:.1f} per "
        f"CPU-second (before {limit_before.fps:.1f}, {limit_before.per_cpu_s:.1f}); "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
