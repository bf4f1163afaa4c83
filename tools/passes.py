"""Which of OpenCV's own parameters read which of the default read's misses, on the corpus.

``python -m tools.passes [--dataset corpus/manifest.json] [--data DIR] [--step 4]
[--max-side 1000] [--max-frames 600] [--only TEXT] [--cells] [--json PATH]``

Reads every labelled item of the manifest whose frames are at most ``--max-side`` pixels a
side (videos: every ``--step``-th frame of the first ``--max-frames``) with OpenCV's default
ArUco parameters and with each setting of :data:`SETTINGS` (threshold windows small and
large, window step, scale, perimeter rate, error correction, polygon accuracy), in the item's
dictionary, no veto. Per footage kind (still or video) and frame size (:data:`SIZES`, by the
frame's lines), for each setting: the labelled id-frames it finds, those of them the default
read missed (its gain; also per marker size, :data:`SIDES`, and per what the default read
found on the frame, :data:`STATES`, which is what a pass's gating can know), the frames it
gains on, the default's finds it loses, the ids it reports that the frame does not hold
(false; a frame with an unread marker or an id out of view leaves them out), and its mean
time per frame. A setting is a pass for a kind of footage only where it gains; one that reads
fewer than the default there is not, even merged with the default's read.

With ``--cells``, every labelled marker a setting finds is also measured as the veto measures
it (:func:`~zenoh_perception.detect.verify.measure`) and binned by pixels per cell along its
shortest side (:data:`CELL_BINS`): per rule, the value of the nearest true tag to its
threshold in each bin, and how many true tags each rule would veto there. That is the veto's
reach on small true markers, the boards' included.

Prints the tables; ``--json`` writes them.
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
from zenoh_perception.detect.second_look import SMALL_SIDE_PX
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import measure
from zenoh_perception.tags.geometry import mean_side
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
    polygon_rate: float = 0.03

    def detector(self, dictionary: str) -> Any:
        params = cv2.aruco.DetectorParameters()
        params.adaptiveThreshWinSizeMin, params.adaptiveThreshWinSizeMax = self.windows[:2]
        params.adaptiveThreshWinSizeStep = self.windows[2]
        params.minMarkerPerimeterRate = self.perimeter_rate
        params.errorCorrectionRate = self.error_correction
        params.polygonalApproxAccuracyRate = self.polygon_rate
        return aruco_detector((dictionary,), params)


#: The default first; then one parameter moved at a time (threshold windows small and large,
#: their step, the scale, perimeter rate, error correction, polygon accuracy), then the
#: combinations the table asks about.
SETTINGS: Final = (
    Setting("default"),
    Setting("error correction 1.0", error_correction=1.0),
    Setting("perimeter 0.01", perimeter_rate=0.01),
    Setting("polygon accuracy 0.06", polygon_rate=0.06),
    Setting("windows 3-53 step 4", windows=(3, 53, 4)),
    Setting("windows 3-53 step 4, perimeter 0.02", windows=(3, 53, 4), perimeter_rate=0.02),
    Setting("windows 3-13 step 2", windows=(3, 13, 2)),
    Setting("windows 5-9 step 2", windows=(5, 9, 2)),
    Setting("windows 5-9 step 4", windows=(5, 9, 4)),
    Setting("windows 23-63 step 20", windows=(23, 63, 20)),
    Setting("1.5x, windows 7-15 step 8", scale=1.5, windows=(7, 15, 8)),
    Setting("2x, window 13", scale=2.0, windows=(13, 13, 10)),
    Setting("2x, windows 7-23 step 8", scale=2.0, windows=(7, 23, 8)),
    Setting("2x, windows 9-17 step 8", scale=2.0, windows=(9, 17, 8)),
    Setting("2x, windows 3-23 step 10", scale=2.0),
    Setting("2x, windows 5-13 step 4", scale=2.0, windows=(5, 13, 4)),
    Setting("2x, windows 9-17 step 8, polygon 0.06", 2.0, (9, 17, 8), polygon_rate=0.06),
    Setting("2x, windows 9-17 step 8, error correction 1.0", 2.0, (9, 17, 8), error_correction=1.0),
    Setting("3x, windows 7-23 step 8", scale=3.0, windows=(7, 23, 8)),
    Setting("0.5x", scale=0.5),
)
#: Frame size bands by the shorter side (the frame's lines, portrait or landscape), pixels.
SIZES: Final = (
    (0, 240, "<= 240 lines"),
    (241, 480, "241-480 lines"),
    (481, 100_000, "> 480 lines"),
)
#: Marker size bands, mean side in pixels (of the marker as the setting read it).
SIDES: Final = (0.0, 16.0, 24.0, 32.0, 64.0, 1e9)
#: What the default read found on the frame: nothing, a marker of at most the look's
#: ``SMALL_SIDE_PX`` (mean side), or only larger ones. A pass's gain is counted per state: a
#: state where no pass gains is one where the look cannot help.
STATES: Final = ("none found", "a marker <= 32 px", "all > 32 px")
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
    """The frame size band of a frame of ``shape`` (:data:`SIZES`)."""
    lines = min(shape[:2])
    return next(name for low, high, name in SIZES if low <= lines <= high)


def side_band(side: float) -> str:
    """The marker size band of a marker of mean side ``side`` (:data:`SIDES`)."""
    low, high = next((lo, hi) for lo, hi in itertools.pairwise(SIDES) if side < hi)
    return f"{low:g}-{high:g}" if high < 1e8 else f">= {low:g}"


def state(found: Sequence[Detection]) -> str:
    """What the default read ``found`` on a frame (:data:`STATES`)."""
    if not found:
        return STATES[0]
    return STATES[1] if min(mean_side(d.corners) for d in found) <= SMALL_SIDE_PX else STATES[2]


def _cell() -> dict[str, Any]:
    return {
        "frames": 0,
        "labelled": 0,
        "found": 0,
        "gain": 0,
        "lost": 0,
        "false": 0,
        "s": 0.0,
        "frames gained": 0,
        "gain by side": {},
        "gain by state": {},
        "frames by state": {},
    }


def _count(table: dict[str, int], key: str, n: int = 1) -> None:
    table[key] = table.get(key, 0) + n


def study(
    manifest: Path,
    data: Path | None,
    step: int,
    max_side: int,
    max_frames: int = 600,
    *,
    only: str = "",
    cells: bool = False,
) -> dict[str, Any]:
    """The tables (see the module documentation) as plain data: items whose name holds
    ``only``; the veto's table per cell with ``cells``."""
    items = [i for i in load_manifest(manifest) if i.markers and only in i.name]
    folder = data_folder(manifest, data)
    table: dict[str, dict[str, dict[str, Any]]] = {}
    per_item: dict[str, dict[str, int]] = {}
    measured: list[tuple[str, float, Measures]] = []  # (setting, px per cell, measures)
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
        gains = per_item.setdefault(item.name, {})
        for index, image in enumerate(stream):
            if kind == "video" and index % step:
                continue
            gray = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)
            labels = item.frame(index)
            labelled = set(labels.markers)
            unread = item.unknown_markers > 0 or item.unsure
            row = table.setdefault(f"{kind} {size_class(gray.shape)}", {})
            default_ids: set[int] = set()
            frame_state = STATES[0]
            for setting, detector in zip(SETTINGS, detectors, strict=True):
                start = time.perf_counter()
                found = read(setting, detector, gray, item.dictionary)
                spent = time.perf_counter() - start
                ids = {d.tag_id for d in found}
                if setting.name == "default":
                    default_ids, frame_state = ids, state(found)
                true = ids & labelled
                gained = [d for d in found if d.tag_id in true - default_ids]
                cell = row.setdefault(setting.name, _cell())
                cell["frames"] += 1
                cell["labelled"] += len(labelled)
                cell["found"] += len(true)
                cell["gain"] += len(gained)
                cell["lost"] += len(default_ids & labelled - ids)
                cell["false"] += 0 if unread else len(ids - labelled - labels.out_of_view)
                cell["s"] += spent
                cell["frames gained"] += bool(gained)
                _count(cell["frames by state"], frame_state)
                _count(cell["gain by state"], frame_state, len(gained))
                for d in gained:
                    _count(cell["gain by side"], side_band(mean_side(d.corners)))
                _count(gains, setting.name, len(gained))
                if cells:
                    for d in found:
                        if d.tag_id in true:
                            m = measure(gray, d, item.dictionary)
                            measured.append((setting.name, m.px_per_cell, m))
    return {"table": table, "items": per_item, "cells": _cell_table(measured)}


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


def _print_table(table: dict[str, dict[str, dict[str, Any]]]) -> None:
    bands = [side_band(low) for low in SIDES[:-1]]
    for key in sorted(table):
        print(f"\n{key}")
        heads = ("frames", "found", "gain", "lost", "false", "ms", "fr+")
        print(
            f"{'setting':40} "
            + " ".join(f"{h:>6}" for h in heads)
            + "  gain by side "
            + "/".join(bands)
            + "  gain by state "
            + "/".join(STATES)
        )
        for name, c in table[key].items():
            ms = 1000 * c["s"] / max(c["frames"], 1)
            by_side = "/".join(str(c["gain by side"].get(b, 0)) for b in bands)
            by_state = "/".join(str(c["gain by state"].get(s, 0)) for s in STATES)
            print(
                f"{name:40} {c['frames']:6d} {c['found']:6d} {c['gain']:6d} {c['lost']:6d}"
                f" {c['false']:6d} {ms:6.2f} {c['frames gained']:6d}  {by_side:>20}  {by_state}"
            )
        first = next(iter(table[key].values()))["frames by state"]
        print("frames by state: " + ", ".join(f"{s} {first.get(s, 0)}" for s in STATES))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.passes", description=__doc__)
    parser.add_argument("--dataset", type=Path, default=Path("corpus/manifest.json"))
    parser.add_argument("--data", type=Path, help="the pictures' folder (default: data/ beside it)")
    parser.add_argument("--step", type=int, default=4, help="every STEP-th video frame")
    parser.add_argument("--max-side", type=int, default=1000)
    parser.add_argument("--max-frames", type=int, default=600, help="a video's first frames")
    parser.add_argument("--only", default="", help="the items whose name holds this")
    parser.add_argument("--cells", action="store_true", help="the veto's table per cell too")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = study(
        args.dataset,
        args.data,
        args.step,
        args.max_side,
        args.max_frames,
        only=args.only,
        cells=args.cells,
    )
    _print_table(result["table"])
    print("\ngain per item (settings that gain there)")
    for item, gains in result["items"].items():
        shown = {k: v for k, v in gains.items() if v}
        if shown:
            print(f"{item}: {shown}")
    if args.cells:
        print("\npx a cell: true tags any setting read, the nearest per rule, what the veto takes")
        for name, row in result["cells"].items():
            shown = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}
            print(f"{name:>9}: {shown}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
