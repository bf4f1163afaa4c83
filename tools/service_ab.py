"""Two versions of the service side by side, and the reading peer: paired, frame by frame.

``python -m tools.service_ab --old DIR --new DIR [--frames 24] [--passes 3] [--seed 2044]
[--bytes] [--flags "--no-verify ..."] [--json PATH]``

``DIR`` is a checkout of the repository (``git archive REV | tar -x -C DIR``); each service
is ``zenoh-perception run`` started with that checkout first on ``PYTHONPATH``, with the
lockstep's frame deadline (:data:`~zenoh_perception_bench.e2e.LOCKSTEP_DEADLINE_MS`) and
``--flags``. Beside them, the bench's reading peer (a Zenoh peer reading each frame with
OpenCV's default in its callback, ``bench --overhead``'s). Every generated HD720 frame with
look-alikes goes to the three in lockstep, the order rotating each frame, from a shared-memory
camera (``--bytes``: plain bytes).

Printed (and appended to ``--json`` as one line): the medians of the per-frame differences,
ms, of each service against the peer and of the new against the old, to ``tag`` and to the
record; and each process's CPU time per frame (``/proc``: user + system, every thread), which
a busy machine moves far less than the latencies. Figures, no verdict.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.e2e import LOCKSTEP_DEADLINE_MS
from zenoh_perception_bench.overhead import frames_at
from zenoh_perception_bench.processes import (
    OPENCV_PEER,
    Camera,
    Remote,
    ServiceProcess,
    raw_frame,
)
from zenoh_perception_bench.runners import rotation

PEER = "peer"
VERSIONS = ("old", "new")
RECORD_TIMEOUT_S = 30.0


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far, every thread."""
    fields = Path(f"/proc/{pid}/stat").read_text(encoding="ascii").rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _started(name: str, endpoint: str, root: Path | None, flags: Sequence[str]) -> ServiceProcess:
    """The peer (``root`` None) or a service from the checkout at ``root``."""
    saved = os.environ.get("PYTHONPATH")
    cwd = Path.cwd()
    if root is not None:  # the child's imports: that checkout's package and bench first
        os.environ["PYTHONPATH"] = f"{root}{os.pathsep}{root / 'bench'}"
        # ``python -m`` puts the current directory before PYTHONPATH: started from another
        # checkout's root, the child would import that checkout's package
        os.chdir(root)
    try:
        if root is None:
            return ServiceProcess(name, OPENCV_PEER, endpoint)
        return ServiceProcess(name, "opencv", endpoint, extra=flags)
    finally:
        os.chdir(cwd)
        if saved is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved


def main(
    old: Path,
    new: Path,
    *,
    frames: int = 24,
    passes: int = 3,
    seed: int = 2044,
    shm: bool = True,
    flags: Sequence[str] = (),
) -> dict[str, Any]:
    """The paired figures (see the module documentation)."""
    images = frames_at("HD720", frames, seed, lookalikes=True)
    service_flags = ("--frame-deadline-ms", str(LOCKSTEP_DEADLINE_MS), *flags)
    endpoint = loopback_endpoint()
    camera = Camera(shm)
    times: dict[str, list[float]] = {}
    processes: dict[str, ServiceProcess] = {}
    remotes: dict[str, Remote] = {}
    with zenoh.open(loopback_config(listen=[endpoint])) as session:
        try:
            for name, root in ((PEER, None), *zip(VERSIONS, (old, new), strict=True)):
                processes[name] = _started(name, endpoint, root, service_flags)
                remotes[name] = Remote(session, processes[name])
            for remote in remotes.values():
                remote.wait_ready()
                remote.warm_up(images[0].shape[1], images[0].shape[0], camera)
            time.sleep(0.5)  # the warm-ups' answers
            for remote in remotes.values():
                remote.drain()
                while not remote.record_arrivals.empty():
                    remote.record_arrivals.get_nowait()
            load = [os.getloadavg()[0]]
            before = {name: _cpu_s(p.proc.pid) for name, p in processes.items()}
            turn = 0
            for _ in range(passes):
                for index, image in enumerate(images):
                    frame = raw_frame(image, index)
                    for name in rotation(list(remotes), turn):
                        remote = remotes[name]
                        loaded = camera.load(frame.payload)
                        start = time.perf_counter()
                        remote.publisher.put(loaded, attachment=frame.attachment)
                        tag = remote.wait_answer()
                        record = remote.record_arrivals.get(timeout=RECORD_TIMEOUT_S)
                        del loaded
                        times.setdefault(f"{name}/tag", []).append((tag - start) * 1e3)
                        times.setdefault(f"{name}/record", []).append((record - start) * 1e3)
                    turn += 1
            after = {name: _cpu_s(p.proc.pid) for name, p in processes.items()}
            load.append(os.getloadavg()[0])
        finally:
            for remote in remotes.values():
                remote.close()
            for process in processes.values():
                process.stop()
    count = len(times[f"{PEER}/tag"])
    series = {key: np.asarray(values) for key, values in times.items()}

    def paired(first: str, second: str, to: str) -> float:
        return round(float(np.median(series[f"{first}/{to}"] - series[f"{second}/{to}"])), 3)

    return {
        "frames": count,
        "load": [round(value, 1) for value in load],
        "camera": "shm" if shm else "bytes",
        "flags": list(flags),
        "peer_tag_ms": round(float(np.median(series[f"{PEER}/tag"])), 3),
        **{
            f"{name}_vs_peer_{to}_ms": paired(name, PEER, to)
            for name in VERSIONS
            for to in ("tag", "record")
        },
        **{f"new_minus_old_{to}_ms": paired("new", "old", to) for to in ("tag", "record")},
        "cpu_ms_per_frame": {
            name: round((after[name] - before[name]) / count * 1e3, 2) for name in processes
        },
    }


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m tools.service_ab", description=__doc__)
    parser.add_argument("--old", type=Path, required=True)
    parser.add_argument("--new", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=2044)
    parser.add_argument("--bytes", action="store_true", help="plain bytes, not shared memory")
    parser.add_argument("--flags", default="", help="more flags of both services' run")
    parser.add_argument("--json", type=Path, help="append the figures as one JSON line")
    return parser.parse_args(argv)


if __name__ == "__main__":
    args = _parse(sys.argv[1:])
    found = main(
        args.old.resolve(),
        args.new.resolve(),
        frames=args.frames,
        passes=args.passes,
        seed=args.seed,
        shm=not args.bytes,
        flags=args.flags.split(),
    )
    print(json.dumps(found))
    if args.json is not None:
        with args.json.open("a", encoding="utf-8") as out:
            out.write(json.dumps(found) + "\n")
