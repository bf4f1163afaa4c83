"""``zenoh-perception bench``: the tracking detector against OpenCV's default, side by side, on
generated frame sets, OpenCV's best setting shown beside.

The bench, top down:

- :mod:`~zenoh_perception_bench.framesets`: the generated frames (exact ground truth) and how
  many (:class:`~zenoh_perception_bench.framesets.Plan`: full, or ``--quick``);
- :mod:`~zenoh_perception_bench.runners`: OpenCV's default (``baseline``), OpenCV's best
  setting (``best``: shown, not judged) and the ``tracking`` detector as the service runs it,
  on every frame, in one process;
- :mod:`~zenoh_perception_bench.scoring`: per set and detector, median / p99 / mean time,
  recall, false positives, centre and distance error;
- :mod:`~zenoh_perception_bench.e2e`: the independent HD720 frames and both drives end to end,
  in lockstep through service processes and the transport floor, ``--passes`` times each
  (each pass with fresh service processes, so each starts as cold as one run does, tracks and
  caches included), pooled, each pass's own-cost ratio reported as well;
- :mod:`~zenoh_perception_bench.throughput`: HD1080 at 60 Hz to a service process;
- the board case (:func:`~zenoh_perception_bench.runners.board_case`): checkerboards and tiled
  floors of 8-20 px squares over half an HD720 frame with tags beside, OpenCV's default and
  the service's detector frame by frame, then a good frame after that storm;
- :mod:`~zenoh_perception_bench.goals`, :mod:`~zenoh_perception_bench.report` and
  :mod:`~zenoh_perception_bench.plot`: the verdicts, the text report and the PNG.

The JSON report (``--json``) holds every figure; ``e2e_setup`` says how the end-to-end figures
were made (shared memory or plain bytes, and why if shared memory was unavailable).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, Final

import cv2
import numpy as np

from zenoh_perception import __version__
from zenoh_perception.detect.tracking import tracking_counters
from zenoh_perception_bench.e2e import Image, Lockstep, lockstep, paced_images
from zenoh_perception_bench.framesets import (
    RESOLUTIONS,
    VIDEO_RESOLUTION,
    FrameSet,
    Plan,
    board_frames,
    frame_sets,
)
from zenoh_perception_bench.goals import goals
from zenoh_perception_bench.lookalikes import lookalike_report
from zenoh_perception_bench.plot import plot
from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR, Camera, sigterm_exits
from zenoh_perception_bench.progress import Progress
from zenoh_perception_bench.reach import DISTANCES_M, range_report
from zenoh_perception_bench.report import format_report
from zenoh_perception_bench.runners import (
    BEST,
    DICTIONARY,
    Baseline,
    Best,
    Project,
    board_case,
    compare,
)
from zenoh_perception_bench.scene.boards import BOARD_KINDS, busy_board_scene
from zenoh_perception_bench.scene.lookalikes import FAMILIES, LOOKALIKE_KINDS
from zenoh_perception_bench.scoring import rounded
from zenoh_perception_bench.throughput import THROUGHPUT_HZ, measure_throughput

#: The frame sets measured end to end.
E2E_SETS: Final = (VIDEO_RESOLUTION, "video", "real-camera video")
#: About how many board frames the paced run sends at 30 Hz (the board frames repeated).
PACED_FRAMES: Final = 96


def run_bench(plan: Plan, *, with_e2e: bool = True, shm: bool = True) -> dict[str, Any]:
    """Measure everything; returns the JSON-ready report (see the module doc). ``shm``: the
    end-to-end camera puts frames from shared memory (else plain bytes)."""
    work = (len(RESOLUTIONS) * plan.frames + plan.video_frames + plan.distractor_frames) * 2
    work += (plan.frames + plan.video_frames) * 2
    work += len(FAMILIES) * (len(LOOKALIKE_KINDS) + 1) * plan.lookalike_frames
    work += len(DISTANCES_M) * plan.range_frames
    work += len(BOARD_KINDS) * len(plan.board_squares)
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
            "lookalike_frames": plan.lookalike_frames,
            "throughput_s": plan.throughput_s,
            "seed": plan.seed,
            "e2e_passes": plan.e2e_passes,
            "busy_board_frames": plan.busy_board_frames,
            "range_frames": plan.range_frames,
        },
        "sets": {},
    }
    for frame_set in sets:
        project = Project()
        baseline_tally, best_tally, project_tally = compare(
            frame_set.scenes, [Baseline(), Best(), project], progress, f"detect {frame_set.name}"
        )
        report["sets"][frame_set.name] = {
            "resolution": frame_set.resolution,
            "video": frame_set.video,
            "baseline": baseline_tally.summary(),
            BEST: best_tally.summary(),
            "tracking": project_tally.summary(),
            "tracking_counters": tracking_counters(project.detector),
        }
    if with_e2e:
        report["e2e"] = _end_to_end(sets, progress, shm=shm, passes=plan.e2e_passes)
        report["throughput"] = measure_throughput(plan, progress, shm=shm)
        report["e2e_setup"] = _e2e_setup(report, shm)
    # a storm of board frames, then a good frame: the HD720 set's first
    after = next(s for s in sets if s.name == VIDEO_RESOLUTION).scenes[0].image
    boards = board_frames(plan)
    report["boards"] = board_case(boards, after, progress)
    if with_e2e:
        # the same storm as a camera sends it: at 30 Hz, a plain frame every fourth, never
        # waiting for an answer, into the default service's process
        storm = [board.image for board in boards] * max(1, PACED_FRAMES // len(boards))
        report["boards"]["paced"] = paced_images("opencv", storm, after, shm=shm)
        report["boards"]["busy"] = busy_board(after, shm=shm, frames=plan.busy_board_frames)
    report["lookalikes"] = lookalike_report(plan.lookalike_frames, plan.seed, progress=progress)
    report["range"] = range_report(plan.range_frames, plan.seed, progress=progress)
    report["goals"] = goals(report)
    return report


def busy_board(after: Image, *, shm: bool, frames: int) -> dict[str, Any]:
    """A board no read finishes within the frame deadline (:func:`~zenoh_perception_bench.scene.
    boards.busy_board_scene`), sent at 5 Hz into the default service's process, ``after`` in
    place of every tenth frame: how many frames are answered with the board's tags, beside
    OpenCV's default time on one such frame."""
    scene = busy_board_scene()
    _, opencv_ms = Baseline(DICTIONARY).run(scene.image)
    ids = frozenset(tag_id for tag_id, _ in scene.markers)
    run = paced_images(
        "opencv", [scene.image] * frames, after, rate_hz=5.0, plain_every=10, shm=shm, ids=ids
    )
    return {**run, "opencv_ms": opencv_ms, "board_frames": frames - frames // 10}


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
                ratios[name].append(rounded(own / stat(bare_pass)))
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
            "median_ms": rounded(np.median(bare_times)),
            "mean_ms": rounded(bare_times.mean()),
            "p99_ms": rounded(np.percentile(bare_times, 99)),
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
        summary[f"{name}_median_ms"] = rounded(np.median(values)) if values.size else None
        summary[f"{name}_mean_ms"] = rounded(values.mean()) if values.size else None
    overhead = np.asarray(run.overhead_ms(), dtype=np.float64)
    summary["overhead_median_ms"] = rounded(np.median(overhead)) if overhead.size else None
    summary["overhead_mean_ms"] = rounded(overhead.mean()) if overhead.size else None
    return summary


def main(args: argparse.Namespace) -> int:
    """Run the generated bench from parsed ``bench`` arguments; 1 when a goal fails."""
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
    with sigterm_exits():
        report = run_bench(plan, with_e2e=not args.no_e2e, shm=not args.no_shm)
    print(format_report(report))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    if args.plot is not None:
        plot(report, args.plot)
    return 0 if all(g["pass"] for g in report["goals"]) else 1
