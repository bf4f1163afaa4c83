"""The approach set: frames of a rover closing in on a tag, for the coarse first read.

A tag of :data:`TAG_SIZE_M` grows from :data:`SIDE_PX` [0] to [1] pixels across (log-spaced,
so each size is as common), nearly face on, wandering about the image centre; beside it a
second tag half its size, a little farther, and two look-alikes (a glyph and a bare code of
the dictionary) at about its distance, one of them up to 1.3 times its size (a look-alike
larger than the true tag is what the veto must judge on full-resolution pixels). Motion blur
up to :data:`MOTION_BLUR_PX` and the generator's realistic effects (textured ground,
clutter, noise, lighting). Each frame is independent (its effects drawn afresh), its
truth the tag's side.

``python -m zenoh_perception_bench.approach [--frames N] [--seed S] [--json PATH]``
(:func:`main`) times the approach the way a user sees it: per resolution (HD720, HD1080),
each frame goes in lockstep, the order rotating per frame, to the reading peer (the transport
floor reading each frame with OpenCV's default in its callback,
:data:`~zenoh_perception_bench.processes.OPENCV_PEER`), to ``zenoh-perception run`` with the
coarse first read (``--coarse-first-read``) and to one without it (the default): put ->
``tag``, and for the services put -> record (waited for before the next step, as a camera's
next frame would come after it). Paired frame by frame: per frame the service's time over the
peer's and minus it, medians per range of the tag's side (under and from
:data:`NEAR_SIDE_PX`), beside the goals (:data:`NEAR_RATIO_GOAL`, :data:`FAR_EXCESS_GOAL_MS`),
and each process's CPU time per answered frame.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import (
    OPENCV_PEER,
    Camera,
    Remote,
    ServiceProcess,
    raw_frame,
)
from zenoh_perception_bench.runners import rotation
from zenoh_perception_bench.scene import (
    CameraModel,
    DistractorPose,
    Effects,
    MarkerPose,
    SceneGenerator,
)

#: The approached tag's side, pixels: from, to.
SIDE_PX: Final = (30.0, 400.0)
#: The approached tag's side, metres.
TAG_SIZE_M: Final = 0.2
#: Longest motion blur, pixels.
MOTION_BLUR_PX: Final = 6.0
#: The tag's id, and the second tag's.
TAG_ID: Final = 7
SECOND_ID: Final = 3


@dataclass(frozen=True, slots=True)
class ApproachFrame:
    """One frame of the approach: BGRA pixels and the approached tag's side (pixels)."""

    image: npt.NDArray[np.uint8]
    side_px: float


def approach_frames(resolution: str, count: int, seed: int = 0) -> list[ApproachFrame]:
    """``count`` frames of ``resolution`` (a name of
    :data:`~zenoh_perception.resolutions.RESOLUTIONS`) along one approach (see the module
    documentation), deterministic for ``seed``."""
    camera = CameraModel.named(resolution)
    effects = replace(Effects.realistic(), motion_blur_px=(0.0, MOTION_BLUR_PX))
    scenes = SceneGenerator(camera, seed=seed, effects=effects)
    rng = np.random.default_rng(seed)
    low, high = SIDE_PX
    frames = []
    for index in range(count):
        side = low * (high / low) ** (index / max(1, count - 1))
        z = camera.fx * TAG_SIZE_M / side
        # the tag within a quarter of the image's width of its centre, the others beside it
        reach = 0.25 * camera.width / camera.fx * z
        x = float(rng.uniform(-reach, reach))
        y = float(rng.uniform(-0.5, 0.5)) * reach
        away = math.copysign(1.0, -x) if x else 1.0
        gap = TAG_SIZE_M * 1.6
        markers = [
            MarkerPose(TAG_ID, TAG_SIZE_M, (x, y, z), yaw_deg=float(rng.uniform(-25, 25))),
            MarkerPose(
                SECOND_ID,
                TAG_SIZE_M / 2,
                (x + away * gap, y - TAG_SIZE_M * 0.4, z * 1.2),
                yaw_deg=float(rng.uniform(-25, 25)),
            ),
        ]
        lookalike = TAG_SIZE_M * float(rng.uniform(0.6, 1.3))
        distractors = [
            DistractorPose("glyph", lookalike, (x - away * gap * 1.2, y, z * 1.1), None, 5),
            DistractorPose(
                "bare_code", TAG_SIZE_M * 0.7, (x + away * gap, y + TAG_SIZE_M, z * 1.05), None, 9
            ),
        ]
        scene = scenes.scene_from_poses(markers, distractors)
        frames.append(ApproachFrame(scene.image, side))
    return frames


#: The tag's side (pixels) from which the service's ``tag`` should come in at most
#: :data:`NEAR_RATIO_GOAL` of the peer's time; under it, at most :data:`FAR_EXCESS_GOAL_MS`
#: after the peer's.
NEAR_SIDE_PX: Final = 60.0
NEAR_RATIO_GOAL: Final = 0.5
FAR_EXCESS_GOAL_MS: Final = 0.3
#: The paths timed: the peer, the service with its coarse first read, the service without.
PATHS: Final = (OPENCV_PEER, "coarse", "whole")
RESOLUTIONS: Final = ("HD720", "HD1080")
#: How long a frame's ``tag`` and record are waited for (a frame abandoned at the frame
#: deadline, on a loaded machine, has neither: left out of the medians).
RECORD_TIMEOUT_S: Final = 5.0


def _cpu_s(pid: int) -> float:
    """CPU time (user + system) the process ``pid`` has used, seconds (Linux)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _processes(endpoint: str) -> list[ServiceProcess]:
    return [
        ServiceProcess(OPENCV_PEER, OPENCV_PEER, endpoint),
        ServiceProcess("coarse", "opencv", endpoint, extra=("--coarse-first-read",)),
        ServiceProcess("whole", "opencv", endpoint),
    ]


def lockstep(frames: dict[str, list[ApproachFrame]]) -> dict[str, dict[str, Any]]:
    """resolution -> per path: put -> ``tag`` ms per frame, the services' put -> record ms,
    and the CPU seconds each process used over the frames (see the module documentation)."""
    endpoint = loopback_endpoint()
    camera = Camera(True)
    out: dict[str, dict[str, Any]] = {}
    with zenoh.open(loopback_config(listen=[endpoint])) as session:
        processes = _processes(endpoint)
        remotes: dict[str, Remote] = {}
        try:
            remotes = {p.name: Remote(session, p) for p in processes}
            for remote in remotes.values():
                remote.wait_ready()
            for resolution, approach in frames.items():
                out[resolution] = _run(remotes, camera, approach)
        finally:
            for remote in remotes.values():
                remote.close()
            for process in processes:
                process.stop()
    return out


def _run(
    remotes: dict[str, Remote], camera: Camera, approach: list[ApproachFrame]
) -> dict[str, Any]:
    height, width = approach[0].image.shape[:2]
    for remote in remotes.values():
        remote.warm_up(width, height, camera)
    time.sleep(0.2)  # the warm-ups' records
    for remote in remotes.values():
        remote.drain()
        while not remote.record_arrivals.empty():
            remote.record_arrivals.get_nowait()
    tag: dict[str, list[float]] = {name: [] for name in PATHS}
    record: dict[str, list[float]] = {name: [] for name in PATHS}
    cpu = {name: _cpu_s(remotes[name].service.proc.pid) for name in PATHS}
    for index, frame in enumerate(approach):
        raw = raw_frame(frame.image, index)
        for name in rotation(PATHS, index):
            remote = remotes[name]
            loaded = camera.load(raw.payload)
            start = time.perf_counter()
            remote.publisher.put(loaded, attachment=raw.attachment)
            try:
                answered = remote.tags.get(timeout=RECORD_TIMEOUT_S)
            except queue.Empty:  # abandoned at the frame deadline (a loaded machine)
                remote.service.check()
                answered = math.nan
            tag[name].append((answered - start) * 1e3)
            try:
                arrived = remote.record_arrivals.get(
                    timeout=0.0 if math.isnan(answered) else RECORD_TIMEOUT_S
                )
            except queue.Empty:  # the frame's record lost (its read abandoned after its tag)
                arrived = math.nan
            record[name].append((arrived - start) * 1e3)
            del loaded
    used = {name: _cpu_s(remotes[name].service.proc.pid) - cpu[name] for name in PATHS}
    return {
        "sides_px": [f.side_px for f in approach],
        "tag_ms": tag,
        "record_ms": record,
        "cpu_ms_per_frame": {n: round(used[n] * 1e3 / len(approach), 2) for n in PATHS},
    }


def summary(run: dict[str, Any]) -> list[dict[str, Any]]:
    """Per range of the tag's side: the paired medians (see the module documentation)."""
    sides = np.asarray(run["sides_px"])
    tag = {n: np.asarray(v) for n, v in run["tag_ms"].items()}
    rows = []
    # frames every path answered (one abandoned at the deadline is left out)
    answered = np.all([np.isfinite(v) for v in tag.values()], axis=0)
    for label, chosen in (
        (f"< {NEAR_SIDE_PX:g} px", answered & (sides < NEAR_SIDE_PX)),
        (f">= {NEAR_SIDE_PX:g} px", answered & (sides >= NEAR_SIDE_PX)),
    ):
        if not chosen.any():
            continue
        peer = tag[OPENCV_PEER][chosen]
        row: dict[str, Any] = {"tags": label, "frames": int(chosen.sum())}
        row["peer_ms"] = round(float(np.median(peer)), 3)
        for name in ("coarse", "whole"):
            mine = tag[name][chosen]
            row[f"{name}_ms"] = round(float(np.median(mine)), 3)
            row[f"{name}_over_peer"] = round(float(np.median(mine / peer)), 3)
            row[f"{name}_minus_peer_ms"] = round(float(np.median(mine - peer)), 3)
            record = np.asarray(run["record_ms"][name])[chosen]
            row[f"{name}_record_ms"] = round(float(np.nanmedian(record)), 3)
        if label.startswith(">="):
            row["goal"] = f"coarse/peer <= {NEAR_RATIO_GOAL}"
            row["met"] = row["coarse_over_peer"] <= NEAR_RATIO_GOAL
        else:
            row["goal"] = f"coarse - peer <= {FAR_EXCESS_GOAL_MS} ms"
            row["met"] = row["coarse_minus_peer_ms"] <= FAR_EXCESS_GOAL_MS
        rows.append(row)
    return rows


def report(runs: dict[str, dict[str, Any]]) -> str:
    lines = [
        "approach set, lockstep (order rotating), put -> tag; medians of paired per-frame "
        "ratios and differences against the reading peer; coarse = the service (coarse first "
        "read on), whole = the service as it comes (coarse read off)",
        f"{'frames':<10}{'tags':<11}{'n':>4}{'peer':>7}{'coarse':>8}{'whole':>7}"
        f"{'c/peer':>8}{'c-peer':>8}{'w/peer':>8}{'w-peer':>8}{'c rec':>7}{'w rec':>7}  goal",
    ]
    for resolution, run in runs.items():
        for r in summary(run):
            lines.append(
                f"{resolution:<10}{r['tags']:<11}{r['frames']:>4}{r['peer_ms']:>7.2f}"
                f"{r['coarse_ms']:>8.2f}{r['whole_ms']:>7.2f}{r['coarse_over_peer']:>8.2f}"
                f"{r['coarse_minus_peer_ms']:>8.2f}{r['whole_over_peer']:>8.2f}"
                f"{r['whole_minus_peer_ms']:>8.2f}{r['coarse_record_ms']:>7.2f}"
                f"{r['whole_record_ms']:>7.2f}  {r['goal']}: {'met' if r['met'] else 'MISSED'}"
            )
        cpu = run["cpu_ms_per_frame"]
        lines.append(
            f"{resolution:<10}CPU ms per answered frame: peer {cpu[OPENCV_PEER]}, "
            f"coarse {cpu['coarse']}, whole {cpu['whole']}"
        )
    lines.append(f"load average {os.getloadavg()[0]:.1f}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m zenoh_perception_bench.approach")
    parser.add_argument("--frames", type=int, default=60, help="frames per resolution")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    frames = {r: approach_frames(r, args.frames, args.seed) for r in RESOLUTIONS}
    runs = lockstep(frames)
    print(report(runs))
    if args.json is not None:
        rows = {r: summary(run) for r, run in runs.items()}
        args.json.write_text(json.dumps({"rows": rows, "runs": runs}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
