"""The generated look-alike sets of ``zenoh-perception bench``: for every dictionary family,
frames of look-alikes (:func:`~zenoh_perception_bench.scene.lookalikes.lookalike_frame`: key-caps,
book-spine lettering, tiles, other families' markers) and frames of true small tags
(:func:`~zenoh_perception_bench.scene.lookalikes.true_tag_frame`), run through OpenCV's default
detector and the service's (:class:`~zenoh_perception_bench.runners.Project`, the veto
included when ``verify``). Per family: the ids OpenCV and the service report on the
look-alikes (all false), and the true tags each finds (every id OpenCV reads on a true-tag
frame is one of the tags drawn there, or counted false). The goals are
:func:`~zenoh_perception_bench.goals.lookalike_goals`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from zenoh_perception.detect.factory import make_detector
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.runners import Baseline, Project
from zenoh_perception_bench.scene.lookalikes import (
    FAMILIES,
    LOOKALIKE_KINDS,
    lookalike_frame,
    true_tag_frame,
)


def lookalike_report(
    frames: int,
    seed: int,
    *,
    verify: bool = True,
    families: Sequence[str] = FAMILIES,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Per family (one dictionary each, default :data:`FAMILIES`): ``frames`` frames of each
    look-alike kind and of true tags, OpenCV's default and the service's detector side by
    side."""
    out: dict[str, Any] = {}
    for index, dictionary in enumerate(families):
        rng = np.random.default_rng(seed + index)
        opencv = Baseline(dictionary)
        service = Project(dictionary, make_detector("opencv", dictionary), verify=verify)
        row: dict[str, Any] = {"frames": frames * (len(LOOKALIKE_KINDS) + 1)}
        for who in ("opencv", "service"):
            row[who] = {"lookalike_ids": 0, "true_found": 0, "false_ids": 0}
        by_kind: dict[str, dict[str, int]] = {}
        for kind in LOOKALIKE_KINDS:
            counts = {"opencv": 0, "service": 0}
            for _ in range(frames):
                image = lookalike_frame(kind, dictionary, rng)
                for who, runner in (("opencv", opencv), ("service", service)):
                    found = len(runner.run(image)[0])
                    counts[who] += found
                    row[who]["lookalike_ids"] += found
                    row[who]["false_ids"] += found
                tick(progress, f"look-alikes {dictionary}")
            by_kind[kind] = counts
        row["by_kind"] = by_kind
        for _ in range(frames):
            image, tags = true_tag_frame(dictionary, rng)
            drawn = {t.tag_id for t in tags}
            for who, runner in (("opencv", opencv), ("service", service)):
                ids = [d.tag_id for d in runner.run(image)[0]]
                row[who]["true_found"] += sum(1 for i in ids if i in drawn)
                row[who]["false_ids"] += sum(1 for i in ids if i not in drawn)
            tick(progress, f"look-alikes {dictionary}")
        out[dictionary] = row
    return out
