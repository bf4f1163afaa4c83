"""SIGTERM and SIGINT into the real ``zenoh-perception run`` while it is busy: it must exit 0
within the deadline, every time.

Each run starts the real command line (``run``; ``--command demo`` for the demo, which runs
the service in its own process) as a client of a loopback router held here, streams frames of
every size into it (VGA, HD720, HD1080 and HD2K on random blocks, and a checkerboard that keeps
OpenCV busy for seconds and is abandoned at ``frame_deadline_ms``), waits until the service has
answered a few, lets a random moment pass (so that the signal lands anywhere: in a read, in an
abandoned read, in a child process's read, in a publication) and sends SIGTERM or SIGINT, in
turn. ``--burners`` processes spin on the CPU meanwhile, as other work does on a shared
machine. Every run prints its signal, exit code and seconds to exit; the summary gives the
exit codes and the median and longest time. Exit status 0 when every run exited 0 within
``--deadline-s``, 1 otherwise.

    python -m tools.exit_stress --runs 50 --burners 2

Slow (a few seconds a run): not in ``make test``; ``tests/tools/test_exit_stress.py`` runs it
twice.
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import cv2
import numpy as np
import zenoh

from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.wire.frames import RawFrameMeta

REPO = Path(__file__).resolve().parent.parent
FRAMES_KEY = "zed/left/image"
STATUS_KEY = "perception/status"
#: The frame sizes streamed in every run, and the checkerboard (HD720, 10 px squares: seconds
#: in OpenCV's detector, abandoned at the deadline).
SIZES = ("VGA", "HD720", "HD1080", "HD2K")
BOARD = (1280, 720, 10)
#: Longest wait for a signalled process before it is killed and the run counted as hung.
HANG_S = 20.0
SLOW_S = 1.0


@dataclass(frozen=True)
class Frame:
    name: str
    payload: bytes
    attachment: RawFrameMeta


@dataclass(frozen=True)
class Run:
    number: int
    signal: str
    code: int | None  # None: still running after HANG_S, killed
    seconds: float
    processed: int
    detail: str  # the last output lines of a failed run

    @property
    def ok(self) -> bool:
        return self.code == 0


def marker_frame(name: str, rng: np.random.Generator) -> Frame:
    """A BGRA frame of resolution ``name``: random 8 px grey blocks (many contours for the
    detector to reject) around one ArUco marker."""
    width, height = RESOLUTIONS[name]
    blocks = rng.integers(0, 256, ((height + 7) // 8, (width + 7) // 8), dtype=np.uint8)
    gray = np.ascontiguousarray(np.repeat(np.repeat(blocks, 8, 0), 8, 1)[:height, :width])
    side = min(width, height) // 4
    x0, y0 = (width - side) // 2, (height - side) // 2
    quiet = side // 6
    gray[y0 - quiet : y0 + side + quiet, x0 - quiet : x0 + side + quiet] = 255
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    gray[y0 : y0 + side, x0 : x0 + side] = cv2.aruco.generateImageMarker(dictionary, 7, side)
    bgra = np.asarray(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGRA), dtype=np.uint8)
    return Frame(name, bgra.tobytes(), RawFrameMeta(width, height, "bgra8"))


def board_frame() -> Frame:
    """The checkerboard: thousands of candidate quads, seconds in OpenCV's detector."""
    width, height, square = BOARD
    y, x = np.indices((height, width))
    gray = np.asarray(((x // square + y // square) % 2) * 255, dtype=np.uint8)
    return Frame("board", gray.tobytes(), RawFrameMeta(width, height, "mono8"))


def loopback_endpoint() -> str:
    """``tcp/127.0.0.1:PORT`` with a port that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
    return f"tcp/127.0.0.1:{port}"


def router_config(endpoint: str) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


class Camera:
    """Puts ``frames`` in turn, as fast as the service takes them, until stopped."""

    def __init__(self, session: zenoh.Session, frames: Sequence[Frame], seed: int) -> None:
        self._publisher = session.declare_publisher(
            FRAMES_KEY, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._frames = frames
        self._random = random.Random(seed)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._put, name="camera", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _put(self) -> None:
        seq = 0
        while not self._stop.is_set():
            frame = self._random.choice(self._frames)
            seq += 1
            meta = frame.attachment
            attachment = RawFrameMeta(
                meta.width, meta.height, meta.encoding, stamp_ns=time.time_ns(), seq=seq
            )
            self._publisher.put(frame.payload, attachment=attachment.to_msgpack())
            self._stop.wait(self._random.uniform(0.0, 0.03))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._publisher.undeclare()  # type: ignore[no-untyped-call]


def query_status(session: zenoh.Session, timeout: float = 0.5) -> dict[str, Any] | None:
    for reply in session.get(STATUS_KEY, timeout=timeout):
        if reply.ok is not None:
            status: dict[str, Any] = json.loads(reply.ok.payload.to_string())
            return status
    return None


def wait_processed(
    session: zenoh.Session, proc: subprocess.Popen[bytes], count: int, timeout: float
) -> int:
    """Frames the service has processed once at least ``count`` (or at ``timeout``, or when
    it exited by itself)."""
    deadline = time.monotonic() + timeout
    processed = 0
    while time.monotonic() < deadline and proc.poll() is None:
        status = query_status(session)
        processed = 0 if status is None else int(status["frames"]["processed"])
        if processed >= count:
            break
    return processed


@contextmanager
def burners(count: int) -> Iterator[None]:
    """``count`` processes spinning on the CPU meanwhile (each ended by its own handle)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


#: The command lines signalled: the service, and the demo (camera, service and echo in one
#: process, at HD2K) with the same frames streamed into its service besides its own.
COMMANDS = {"run": ("run",), "demo": ("demo", "--resolution", "HD2K", "--fps", "30")}


def one_run(
    number: int,
    command_name: str,
    signum: signal.Signals,
    frames: Sequence[Frame],
    rng: random.Random,
) -> Run:
    endpoint = loopback_endpoint()
    command = [sys.executable, "-m", "zenoh_perception", *COMMANDS[command_name]]
    command += ["-m", "client", "-e", endpoint, "--no-multicast-scouting"]
    command += ["--stats-interval-s", "0"]
    with ExitStack() as stack:
        session = zenoh.open(router_config(endpoint))
        stack.callback(session.close)
        log = stack.enter_context(tempfile.TemporaryFile())
        proc = subprocess.Popen(command, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
        stack.callback(_reap, proc)
        camera = Camera(session, frames, rng.randrange(2**32))
        camera.start()
        stack.callback(camera.stop)
        processed = wait_processed(session, proc, 3, timeout=60.0)
        # anywhere in what the service is doing: a read, an abandoned one, a publication
        time.sleep(rng.uniform(0.0, 1.0))
        started = time.monotonic()
        proc.send_signal(signum)
        try:
            code: int | None = proc.wait(timeout=HANG_S)
        except subprocess.TimeoutExpired:
            code = None
        seconds = time.monotonic() - started
        log.seek(0)
        output = log.read().decode(errors="replace")
    detail = "" if code == 0 and seconds <= SLOW_S else " | ".join(output.strip().splitlines()[-4:])
    return Run(number, signum.name, code, seconds, processed, detail)


def _reap(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def summary(runs: Sequence[Run], deadline_s: float) -> str:
    seconds = [r.seconds for r in runs]
    codes = Counter("hung" if r.code is None else str(r.code) for r in runs)
    slow = sum(r.seconds > deadline_s for r in runs)
    return (
        f"runs={len(runs)} exit_codes={dict(sorted(codes.items()))} "
        f"exit_s_median={statistics.median(seconds):.2f} exit_s_max={max(seconds):.2f} "
        f"over_{deadline_s:g}s={slow}"
    )


def main(
    *,
    runs: int = 50,
    burner_count: int = 2,
    deadline_s: float = 2.0,
    seed: int = 0,
    command: str = "run",
    out: TextIO = sys.stdout,
) -> int:
    """Signal the real ``command`` (``run`` or ``demo``) ``runs`` times; 0 when each run
    exited 0 within ``deadline_s``."""
    rng = random.Random(seed)
    blocks = np.random.default_rng(seed)
    frames = [*(marker_frame(name, blocks) for name in SIZES), board_frame()]
    names = ",".join(f.name for f in frames)
    print(
        f"exit_stress: command={command} runs={runs} burners={burner_count} frames={names}",
        file=out,
        flush=True,
    )
    done: list[Run] = []
    with burners(burner_count):
        for number in range(1, runs + 1):
            signum = signal.SIGTERM if number % 2 else signal.SIGINT
            run = one_run(number, command, signum, frames, rng)
            done.append(run)
            verdict = "ok" if run.ok and run.seconds <= deadline_s else "FAIL"
            line = (
                f"run {number}/{runs} signal={run.signal} processed={run.processed} "
                f"code={run.code} exit_s={run.seconds:.2f} {verdict}"
            )
            print(line + (f" output: {run.detail}" if run.detail else ""), file=out, flush=True)
    print(summary(done, deadline_s), file=out, flush=True)
    return 0 if all(r.ok and r.seconds <= deadline_s for r in done) else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=50, help="runs (default 50)")
    parser.add_argument(
        "--burners", type=int, default=2, help="CPU-burning processes beside it (default 2)"
    )
    parser.add_argument(
        "--deadline-s", type=float, default=2.0, help="longest exit allowed (default 2 s)"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--command", choices=tuple(COMMANDS), default="run", help="what to signal (default run)"
    )
    args = parser.parse_args()
    sys.exit(
        main(
            runs=args.runs,
            burner_count=args.burners,
            deadline_s=args.deadline_s,
            seed=args.seed,
            command=args.command,
        )
    )
