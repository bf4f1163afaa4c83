"""Whether the coarse first read answers ``tag`` as the whole read does, frame by frame.

``python -m tools.coarse_agreement [--dataset corpus/manifest.json] [--data DIR]
[--approach N] [--max-frames N] [--json PATH]``

Two pipelines of the service's default settings read the same frames in order, one with the
coarse first read (``coarse_first_read``) and one without: per frame, the tag the first
publishes (from its coarse read where it took one) against the second's. Frames are the
corpus's videos and sequences (every frame, in the item's dictionary) and the approach sets
(:mod:`zenoh_perception_bench.approach`) at HD720 and HD1080, ``--approach`` frames each,
several seeds. Prints, per source: frames, those answered from the coarse read, those whose
answer differs (another id, a centre more than 0.5 px away or a closeness more than 0.002
away: :func:`~zenoh_perception.detect.coarse.same_answer`), the largest centre and
closeness differences where the ids agree, and the whole read's and the coarse read's
median time per frame, and the slow coarse reads (each resting the coarse read for the
stream's next frames, as in the service: on a loaded machine they lower the frames answered
from it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.coarse import same_answer
from zenoh_perception.pipeline import Pipeline
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import ENCODINGS, Frame
from zenoh_perception_bench.approach import approach_frames
from zenoh_perception_bench.footage import data_folder, frames
from zenoh_perception_bench.manifest import load_manifest

SEEDS = (1, 2, 3)


def compare(images: Iterable[npt.NDArray[np.uint8]], settings: Settings) -> dict[str, Any]:
    """One source's frames through both pipelines (see the module documentation)."""
    coarse = Pipeline(replace(settings.detection, coarse_first_read=True), settings.selection)
    whole = Pipeline(replace(settings.detection, coarse_first_read=False), settings.selection)
    assert coarse.coarse is not None
    counters = coarse.coarse.counters
    count = answered = differ = 0
    centre = closeness = 0.0
    whole_ms: list[float] = []
    coarse_ms: list[float] = []
    for index, image in enumerate(images):
        frame = Frame(image, ENCODINGS["bgra8"], None, "agreement", index)
        start = time.perf_counter()
        reference = whole.begin(frame)
        whole_ms.append((time.perf_counter() - start) * 1e3)
        reference.finish()
        start = time.perf_counter()
        pending = coarse.begin(frame)
        coarse_ms.append((time.perf_counter() - start) * 1e3)
        pending.finish()
        count += 1
        early = counters["answered"] > answered
        answered = counters["answered"]
        a, b = pending.selected, reference.selected
        if not same_answer(a, b):
            differ += 1
        if early and a.tag_id == b.tag_id:
            centre = max(
                centre,
                float(
                    np.hypot(
                        a.x_tag_center_pixel - b.x_tag_center_pixel,
                        a.y_tag_center_pixel - b.y_tag_center_pixel,
                    )
                ),
            )
            closeness = max(closeness, abs(a.closeness_metric - b.closeness_metric))
    return {
        "frames": count,
        "coarse": answered,
        # reads slowed past SLOW_READ_S (a periodic pattern, or a loaded machine), each reading
        # the stream's next frames whole: fewer answered from the coarse read, not others
        "slow": counters["slow"],
        "differ": differ,
        "centre_max_px": round(centre, 3),
        "closeness_max": round(closeness, 5),
        "whole_ms": round(float(np.median(whole_ms)), 3) if whole_ms else None,
        "coarse_ms": round(float(np.median(coarse_ms)), 3) if coarse_ms else None,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.coarse_agreement")
    parser.add_argument("--dataset", type=Path, default=Path("corpus/manifest.json"))
    parser.add_argument("--data", type=Path, default=None)
    parser.add_argument("--approach", type=int, default=120)
    parser.add_argument("--max-frames", type=int, default=100000)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    rows: dict[str, dict[str, Any]] = {}
    for resolution in ("HD720", "HD1080"):
        for seed in SEEDS:
            images = (f.image for f in approach_frames(resolution, args.approach, seed))
            rows[f"approach {resolution} seed {seed}"] = compare(images, Settings())
            _print(rows)
    data = data_folder(args.dataset, args.data)
    for item in load_manifest(args.dataset):
        if item.kind == "image":
            continue
        settings = Settings.from_flat(dictionary=item.dictionary)
        rows[item.name] = compare(frames(item, data, args.max_frames), settings)
        _print(rows)
    total = {k: sum(r[k] for r in rows.values()) for k in ("frames", "coarse", "differ")}
    print(f"total: {total}")
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": rows, "total": total}, indent=2))
    return 0


def _print(rows: dict[str, dict[str, Any]]) -> None:
    name, r = list(rows.items())[-1]
    print(f"{name:<44}" + " ".join(f"{k}={v}" for k, v in r.items()), flush=True)


if __name__ == "__main__":
    sys.exit(main())
