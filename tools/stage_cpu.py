"""Where a frame's CPU goes, stage by stage: the service's pipeline in process on generated
HD720 frames with look-alikes, each stage's CPU time counted with ``time.thread_time_ns``
(CPU time moves far less than wall time on a busy machine).

``python -m tools.stage_cpu [--frames 24] [--passes 3] [--seed 2044] [--json PATH]``

Per frame, as the service answers it (the deadline's guard around OpenCV's detector, default
settings): the decode (one copy of the payload, as out of Zenoh), the path up to the ``tag``
(its CDR included), the frame's finish (the veto of the other detections, the look after the
tag, the kept tags refined) and the record's msgpack; inside them, each stage's own time
(``[stage]``): OpenCV's read, the grey conversion, the grid keeper, the second look, the
corners' refinement, each tag's geometry, the veto's judgement, the tag's CDR. Figures, no
verdict.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from functools import partial, wraps
from pathlib import Path
from typing import Any

import zenoh_perception.detect.grids as grids_module
import zenoh_perception.detect.opencv as opencv_module
import zenoh_perception.detect.second_look as second_look_module
import zenoh_perception.detect.verify as verify_module
import zenoh_perception.pipeline as pipeline_module
import zenoh_perception.wire.records as records_module
from zenoh_perception.service.guard import GuardedDetector
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import decode_raw_frame
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception_bench.overhead import frames_at
from zenoh_perception_bench.processes import raw_frame

#: The stages counted inside the path: (owner, attribute, name).
STAGES: tuple[tuple[Any, str, str], ...] = (
    (opencv_module.OpenCvDetector, "_detect", "opencv read"),
    (pipeline_module, "to_gray", "grey conversion"),
    (grids_module.GridKeeper, "prepare", "grid keeper"),
    (second_look_module.SecondLook, "look", "second look"),
    (pipeline_module, "refined", "corner refinement"),
    (pipeline_module, "observe", "geometry"),
    (verify_module.Verifier, "judge", "veto"),
    (records_module.TagCodec, "encode", "tag CDR"),
)


def _counted(spent: dict[str, int], name: str, function: Callable[..., Any]) -> Callable[..., Any]:
    @wraps(function)
    def counted(*args: Any, **kwargs: Any) -> Any:
        start = time.thread_time_ns()
        try:
            return function(*args, **kwargs)
        finally:
            spent[name] += time.thread_time_ns() - start

    return counted


def main(frames: int = 24, passes: int = 3, seed: int = 2044) -> dict[str, Any]:
    """CPU ms a frame per step and per stage (see the module documentation)."""
    stages: dict[str, int] = defaultdict(int)
    originals = [(owner, attribute, getattr(owner, attribute)) for owner, attribute, _ in STAGES]
    for owner, attribute, name in STAGES:
        setattr(owner, attribute, _counted(stages, name, getattr(owner, attribute)))
    try:
        return _measure(frames, passes, seed, stages)
    finally:
        for owner, attribute, original in originals:
            setattr(owner, attribute, original)


def _measure(frames: int, passes: int, seed: int, stages: dict[str, int]) -> dict[str, Any]:
    settings = Settings()
    payloads = [
        raw_frame(image, i)
        for i, image in enumerate(frames_at("HD720", frames, seed, lookalikes=True))
    ]
    factory = partial(pipeline_module.detector_for, settings.detection)
    detector = GuardedDetector(factory, 20.0, after_stall=factory)
    pipeline = pipeline_module.Pipeline(settings.detection, settings.selection, detector)
    codec = records_module.TagCodec()
    most_pixels = settings.limits.max_frame_pixels
    steps: dict[str, int] = defaultdict(int)
    tags = 0

    def answer(payload: bytes, attachment: bytes) -> int:
        start = time.thread_time_ns()
        frame = decode_raw_frame(bytes(payload), attachment, max_pixels=most_pixels)
        decoded = time.thread_time_ns()
        pending = pipeline.begin(frame)
        bytes(codec.encode(pending.selected))
        tagged = time.thread_time_ns()
        analysis = pending.finish()
        finished = time.thread_time_ns()
        records_module.FrameRecord(
            stamp_ns=0,
            frame_id=frame.frame_id,
            seq=0,
            width=frame.width,
            height=frame.height,
            selected=analysis.selected,
            tags=analysis.tags,
            timing_ms={"detect_ms": analysis.detect_ms},
            source=InputKind.RAW,
        ).to_msgpack()
        steps["decode"] += decoded - start
        steps["to tag"] += tagged - decoded
        steps["finish"] += finished - tagged
        steps["record"] += time.thread_time_ns() - finished
        return len(analysis.tags)

    for payload in payloads[:4]:  # warm-up
        answer(payload.payload, payload.attachment)
    steps.clear()
    stages.clear()
    for _ in range(passes):
        for payload in payloads:
            tags += answer(payload.payload, payload.attachment)
    count = passes * len(payloads)
    return {
        "frames": count,
        "kept_tags_per_frame": round(tags / count, 2),
        "cpu_ms_per_frame": {k: round(v / count / 1e6, 3) for k, v in steps.items()},
        "stage_cpu_ms_per_frame": {
            k: round(v / count / 1e6, 3) for k, v in sorted(stages.items(), key=lambda kv: -kv[1])
        },
    }


def _report(result: dict[str, Any]) -> str:
    lines = [
        f"{result['frames']} HD720 look-alike frames, {result['kept_tags_per_frame']} tags kept "
        "a frame; CPU ms a frame:"
    ]
    lines += [f"  {k:<20}{v:8.3f}" for k, v in result["cpu_ms_per_frame"].items()]
    lines += [
        f"  [{k}]".ljust(22) + f"{v:8.3f}" for k, v in result["stage_cpu_ms_per_frame"].items()
    ]
    return "\n".join(lines)


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m tools.stage_cpu", description=__doc__)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=2044)
    parser.add_argument("--json", type=Path)
    return parser.parse_args(argv)


if __name__ == "__main__":
    args = _parse(sys.argv[1:])
    found = main(args.frames, args.passes, args.seed)
    print(_report(found))
    if args.json is not None:
        args.json.write_text(json.dumps(found, indent=2))
