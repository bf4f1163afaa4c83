"""Which of OpenCV's own parameters read which of the default read's misses, on the corpus.

``python -m tools.passes [--dataset corpus/manifest.json] [--data DIR] [--step 4]
[--max-side 1000] [--json PATH]``

Reads every labelled item of the manifest whose frames are at most ``--max-side`` pixels a
side (videos: every ``--step``-th frame, as far as the bench reads them) with OpenCV's
default ArUco parameters and with each setting of :data:`SETTINGS` (threshold windows small
and large, window step, scale, perimeter rate, error correction), in the item's dictionary,
no veto. Per footage kind (still or video) and frame size (:data:`SIZES`), for each setting:
the labelled id-frames it finds, those of them the default read missed (its gain), the
default's finds it loses, the ids it reports that the frame does not hold (false; a frame
with an unread marker or an id out of view leaves them out), and its mean time per frame.

Beside the table, every labelled marker a setting finds is measured as the veto measures it
(:func:`~zenoh_perception.detect.verify.measure`) and binned by pixels per cell along its
shortest side (:data:`CELL_BINS`): per rule, the value of the nearest true tag to its
threshold in each bin, and how many true tags each rule would veto there. That is the veto's
reach on small true markers, the boards' included.

Prints both tables; ``--json`` writes them.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_detector, read_markers
from zenoh_perception.detect.rules import Measures, Thresholds, veto_reasons
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import measure
from zenoh_perception_bench.footage import data_folder, frames
from zenoh_perception_bench.manifest import TooLargeError, load_manifest


@dataclass(frozen=True, slots=True)
class Setting:
    """One way of running OpenCV's detector: its parameters, and the scale the frame is read
    at (corners brought back to the frame's pixels)."""

    name: str
    scale: float = 1.0
    windows: tuple[int, int, int] = (3, 23, 10)  # from, to, step: OpenCV's default
    perimeter_rate: float = 0.03
    error_correction: float = 0.6

    def detector(self, dictionary: str) -> Any:
        params = cv2.aruco.DetectorParameters()
        params.adaptiveThreshWinSizeMin, params.adaptiveThreshWinSizeMax = self.windows[:2]
        params.adaptiveThreshWinSizeStep = self.windows[2]
        params.minMarkerPerimeterRate = self.perimeter_rate
        params.errorCorrectionRate = self.error_correction
        return aruco_detector((dictionary,), params)


#: The default first; then one parameter moved at a time, then the combinations the table
#: asks about.
SETTINGS: Final = (
    Setting("default"),
    Setting("error correction 1.0", error_correction=1.0),
    Setting("perimeter 0.01", perimeter_rate=0.01),
    Setting("windows 3-53 step 4", windows=(3, 53, 4)),
    Setting("windows 3-53 step 4, perimeter 0.02", windows=(3, 53, 4), perimeter_rate=0.02),
    Setting("windows 3-13 step 2", windows=(3, 13, 2)),
    Setting("windows 5-9 step 2", windows=(5, 9, 2)),
    Setting("windows 23-63 step 20", windows=(23, 63, 20)),
    Setting("2x, window 13", scale=2.0, windows=(13, 13, 10)),
    Setting("2x, windows 7-23 step 8", scale=2.0, windows=(7, 23, 8)),
    Setting("2x, windows 9-17 step 8", scale=2.0, windows=(9, 17, 8)),
    Setting("2x, windows 3-23 step 10", scale=2.0),
    Setting("2x, windows 5-13 step 4", scale=2.0, windows=(5, 13, 4)),
    Setting("2x, windows 5-13 step 4, perimeter 0.01", 2.0, (5, 13, 4), 0.01),
    Setting("3x, windows 7-23 step 8", scale=3.0, windows=(7, 23, 8)),
    Setting("0.5x", scale=0.5),
)
#: Frame size classes by the longer side, pixels.
SIZES: Final = ((0, 400, "<= 400 px"), (401, 700, "401-700 px"), (701, 100_000, "701-1000 px"))
#: Pixels per cell bins (shortest side over cells across, border included).
CELL_BINS: Final = (0.0, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0, 1e9)
#: Per rule: the measure, and whether a true tag is nearer its threshold when the measure is
#: larger (True) or smaller.
RULES: Final = {
    "quiet_zone (low)": ("quiet", False),
    "quiet_zone (high)": ("quiet", True),
    "border": ("border_light", True),
    "grid": ("grid_ratio", True),
    "strokes": ("strokes", True),
    "margin": ("margin", False),
}


def read(
    setting: Setting, detector: Any, gray: npt.NDArray[np.uint8], dictionary: str
) -> list[Detection]:
    """What ``setting`` reads on ``gray``, corners in ``gray``'s pixels."""
    if setting.scale == 1.0:
        return read_markers(detector, gray, (dictionary,))[0]
    height, width = gray.shape
    size = (round(width * setting.scale), round(height * setting.scale))
    interpolation = cv2.INTER_LINEAR if setting.scale > 1 else cv2.INTER_AREA
    scaled = cv2.resize(gray, size, interpolation=interpolation)
    found = read_markers(detector, scaled, (dictionary,))[0]
    half = np.float32(0.5)
    return [
        Detection(
            d.tag_id,
            np.asarray((d.corners + half) / np.float32(setting.scale) - half, np.float32),
            d.dictionary,
        )
        for d in found
    ]


def size_class(shape: Sequence[int]) -> str:
    longer = max(shape[:2])
    return next(name for low, high, name in SIZES if low <= longer <= high)


def study(
    manifest: Path, data: Path | None, step: int, max_side: int, max_frames: int = 600
) -> dict[str, Any]:
    """The two tables (see the module documentation) as plain data."""
    items = [i for i in load_manifest(manifest) if i.markers]
    folder = data_folder(manifest, data)
    table: dict[str, dict[str, dict[str, float]]] = {}
    cells: list[tuple[str, float, Measures]] = []  # (setting, px per cell, measures) of trues
    for item in items:
        detectors = [s.detector(item.dictionary) for s in SETTINGS]
        kind = "still" if item.kind == "image" else "video"
        try:
            stream = list(frames(item, folder, max_frames))
        except TooLargeError:
            continue
        if max(stream[0].shape[:2]) > max_side:
            continue
        print(f"{item.name}: {len(stream)} frames", file=sys.stderr)
        for index, image in enumerate(stream):
            if kind == "video" and index % step:
                continue
            gray = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)
            labels = item.frame(index)
            key = f"{kind} {size_class(gray.shape)}"
            row = table.setdefault(key, {})
            default_ids: set[int] = set()
            for setting, detector in zip(SETTINGS, detectors, strict=True):
                start = time.perf_counter()
                found = read(setting, detector, gray, item.dictionary)
                spent = time.perf_counter() - start
                ids = {d.tag_id for d in found}
                if setting.name == "default":
                    default_ids = ids
                true = ids & set(labels.markers)
                unread = item.unknown_markers > 0 or item.unsure
                false = set() if unread else ids - set(labels.markers) - labels.out_of_view
                cell = row.setdefault(
                    setting.name,
                    {
                        "frames": 0,
                        "labelled": 0,
                        "found": 0,
                        "gain": 0,
                        "lost": 0,
                        "false": 0,
                        "s": 0.0,
                    },
                )
                cell["frames"] += 1
                cell["labelled"] += len(labels.markers)
                cell["found"] += len(true)
                cell["gain"] += len(true - default_ids)
                cell["lost"] += len(default_ids & set(labels.markers) - ids)
                cell["false"] += len(false)
                cell["s"] += spent
                for d in found:
                    if d.tag_id in true:
                        m = measure(gray, d, item.dictionary)
                        cells.append((setting.name, m.px_per_cell, m))
    return {"table": table, "cells": _cell_table(cells)}


def _cell_table(cells: list[tuple[str, float, Measures]]) -> dict[str, dict[str, Any]]:
    """Per pixels-per-cell bin: true tags, and per rule the nearest one and how many it vetoes."""
    out: dict[str, dict[str, Any]] = {}
    current = Thresholds()
    for low, high in itertools.pairwise(CELL_BINS):
        inside = [m for _s, ppc, m in cells if low <= ppc < high]
        if not inside:
            continue
        name = f"{low:g}-{high:g}" if high < 1e8 else f">= {low:g}"
        row: dict[str, Any] = {"true": len(inside)}
        for rule, (attr, larger) in RULES.items():
            values = [getattr(m, attr) for m in inside if getattr(m, attr) is not None]
            if values:
                row[rule] = max(values) if larger else min(values)
        vetoed: dict[str, int] = {}
        for m in inside:
            for reason in veto_reasons(m, current):
                vetoed[reason] = vetoed.get(reason, 0) + 1
        row["vetoed"] = vetoed
        out[name] = row
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.passes", description=__doc__)
    parser.add_argument("--dataset", type=Path, default=Path("corpus/manifest.json"))
    parser.add_argument("--data", type=Path, help="the pictures' folder (default: data/ beside it)")
    parser.add_argument("--step", type=int, default=4, help="every STEP-th video frame")
    parser.add_argument("--max-side", type=int, default=1000)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = study(args.dataset, args.data, args.step, args.max_side)
    for key in sorted(result["table"]):
        print(f"\n{key}")
        heads = ("frames", "found", "gain", "lost", "false", "ms")
        print(f"{'setting':44} " + " ".join(f"{h:>6}" for h in heads))
        for name, c in result["table"][key].items():
            ms = 1000 * c["s"] / max(c["frames"], 1)
            print(
                f"{name:44} {c['frames']:6d} {c['found']:6d} {c['gain']:6d} {c['lost']:6d}"
                f" {c['false']:6d} {ms:6.2f}"
            )
    print("\npx a cell: true tags any setting read, the nearest per rule, and what the veto takes")
    for name, row in result["cells"].items():
        shown = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}
        print(f"{name:>9}: {shown}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
