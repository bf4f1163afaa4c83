"""The benches' PNGs, drawn with OpenCV (no plotting library needed): the generated bench's
detection latency against resolution, and the labelled-dataset bench's found and false ids
per item and per marker size."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.framesets import RESOLUTIONS
from zenoh_perception_bench.report import negatives_merged
from zenoh_perception_bench.runners import BEST
from zenoh_perception_bench.scoring import BUCKETS

Image = npt.NDArray[np.uint8]


def plot(report: dict[str, Any], path: Path) -> None:
    """PNG of detection latency (median solid, p99 dashed) against resolution."""
    width, height = 960, 600
    left, right, top, bottom = 90, 40, 60, 90
    canvas = np.full((height, width, 3), 255, dtype=np.uint8)
    names = [n for n in RESOLUTIONS if n in report["sets"]]
    series = []
    for who, colour in (
        ("baseline", (40, 40, 220)),
        (BEST, (60, 160, 60)),
        ("tracking", (200, 110, 20)),
    ):
        if any(who not in report["sets"][n] for n in names):
            continue  # OpenCV's best setting: not in a report made before it was run
        med = [report["sets"][n][who]["median_ms"] or 0.0 for n in names]
        p99 = [report["sets"][n][who]["p99_ms"] or 0.0 for n in names]
        series.append((who, colour, med, p99))
    top_ms = max(max(p99) for _, _, _, p99 in series) * 1.1 or 1.0
    plot_w, plot_h = width - left - right, height - top - bottom

    def xy(i: int, ms: float) -> tuple[int, int]:
        x = left + round(plot_w * (i + 0.5) / len(names))
        y = top + plot_h - round(plot_h * ms / top_ms)
        return x, y

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.rectangle(canvas, (left, top), (left + plot_w, top + plot_h), (0, 0, 0), 1)
    step = _nice_step(top_ms / 6)
    tick = 0.0
    while tick <= top_ms:
        y = xy(0, tick)[1]
        cv2.line(canvas, (left, y), (left + plot_w, y), (225, 225, 225), 1)
        cv2.putText(canvas, f"{tick:g}", (left - 60, y + 5), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        tick += step
    for i, name in enumerate(names):
        x = xy(i, 0)[0]
        cv2.putText(canvas, name, (x - 30, top + plot_h + 30), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for _who, colour, med, p99 in series:
        points = [xy(i, v) for i, v in enumerate(med)]
        for a, b in itertools.pairwise(points):
            cv2.line(canvas, a, b, colour, 2, cv2.LINE_AA)
        for p in points:
            cv2.circle(canvas, p, 5, colour, -1, cv2.LINE_AA)
        points = [xy(i, v) for i, v in enumerate(p99)]
        for a, b in itertools.pairwise(points):
            _dashed(canvas, a, b, colour)
    cv2.putText(
        canvas,
        "Detection latency vs resolution (median solid, p99 dashed)",
        (left, 35),
        font,
        0.7,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    cv2.putText(canvas, "ms", (left - 60, top - 12), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for k, (who, colour, _, _) in enumerate(series):
        y = top + 25 + 25 * k
        cv2.line(canvas, (left + 20, y), (left + 60, y), colour, 2, cv2.LINE_AA)
        text = LEGEND[who]
        cv2.putText(canvas, text, (left + 70, y + 5), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), canvas):
        msg = f"cannot write {path}"
        raise OSError(msg)


#: The latency plot's legend, per detector of the generated bench's frame sets.
LEGEND: Final = {
    "baseline": "baseline (BGRA->BGR + OpenCV defaults)",
    BEST: "OpenCV's best setting (shown, not judged)",
    "tracking": "tracking (default)",
}


def _nice_step(raw: float) -> float:
    exponent = math.floor(math.log10(raw)) if raw > 0 else 0
    unit = 10.0**exponent
    for mult in (1.0, 2.0, 5.0):
        if mult * unit >= raw:
            return mult * unit
    return 10.0 * unit


def _dashed(
    canvas: Image, a: tuple[int, int], b: tuple[int, int], colour: tuple[int, int, int]
) -> None:
    length = math.hypot(b[0] - a[0], b[1] - a[1])
    dashes = max(int(length // 10), 1)
    for k in range(0, dashes, 2):
        t0, t1 = k / dashes, min((k + 1) / dashes, 1.0)
        p = (round(a[0] + (b[0] - a[0]) * t0), round(a[1] + (b[1] - a[1]) * t0))
        q = (round(a[0] + (b[0] - a[0]) * t1), round(a[1] + (b[1] - a[1]) * t1))
        cv2.line(canvas, p, q, colour, 1, cv2.LINE_AA)


#: The dataset plot's colours (BGR): OpenCV's default, the service.
OPENCV_COLOUR: Final = (40, 40, 220)
SERVICE_COLOUR: Final = (200, 110, 20)


def plot_dataset(report: dict[str, Any], path: Path) -> None:
    """PNG of the labelled-dataset bench: per item, the share of labelled markers found and
    the false ids, OpenCV's default above the service; then the same per marker size."""
    items = negatives_merged(report["items"])  # a negative: one row over its dictionaries
    row_h, width, left, bar_w = 26, 1100, 360, 420
    buckets_h = 60 + 26 * len(BUCKETS) * 2
    height = 80 + row_h * len(items) + buckets_h
    canvas = np.full((height, width, 3), 255, dtype=np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    black = (0, 0, 0)

    def text(words: str, x: int, y: int, scale: float = 0.45) -> None:
        cv2.putText(canvas, words, (x, y), font, scale, black, 1, cv2.LINE_AA)

    text("Share of labelled markers found (bar) and false ids, per item", 20, 30, 0.65)
    for k, (who, colour) in enumerate(
        (("OpenCV default", OPENCV_COLOUR), ("service", SERVICE_COLOUR))
    ):
        cv2.rectangle(canvas, (20 + 200 * k, 45), (40 + 200 * k, 57), colour, -1)
        text(who, 46 + 200 * k, 57)
    y = 80
    for item in items:
        name = item["name"] if len(item["name"]) <= 44 else item["name"][:41] + "..."
        text(f"{name} {item['dictionary'].removeprefix('DICT_')}", 20, y + 16, 0.4)
        for k, (who, colour) in enumerate((("opencv", OPENCV_COLOUR), ("service", SERVICE_COLOUR))):
            share = item[who]["share_found"]
            top = y + 2 + 11 * k
            cv2.rectangle(canvas, (left, top), (left + bar_w, top + 9), (235, 235, 235), -1)
            if share is not None:
                cv2.rectangle(
                    canvas, (left, top), (left + round(bar_w * share), top + 9), colour, -1
                )
        summary = (
            f"{_share(item['opencv'])} / {_share(item['service'])}  false"
            f" {item['opencv']['false_ids']}/{item['service']['false_ids']}"
        )
        text(summary, left + bar_w + 15, y + 16, 0.4)
        y += row_h
    y += 40
    text("Per marker size (mean side): found on stills and videos, and false ids", 20, y, 0.65)
    y += 20
    every = report["all"]
    most = max(
        1,
        *(
            every[w][key][b]
            for w in ("opencv", "service")
            for key in ("buckets", "false_buckets")
            for b in BUCKETS
        ),
    )
    for bucket in BUCKETS:
        for key, word in (("buckets", "found"), ("false_buckets", "false")):
            text(f"{bucket} {word}", 20, y + 16)
            for k, (who, colour) in enumerate(
                (("opencv", OPENCV_COLOUR), ("service", SERVICE_COLOUR))
            ):
                value = every[who][key][bucket]
                top = y + 2 + 11 * k
                cv2.rectangle(
                    canvas, (left, top), (left + round(bar_w * value / most), top + 9), colour, -1
                )
            text(
                f"{every['opencv'][key][bucket]} / {every['service'][key][bucket]}",
                left + bar_w + 15,
                y + 16,
            )
            y += row_h
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), canvas):
        msg = f"cannot write {path}"
        raise OSError(msg)


def _share(summary: dict[str, Any]) -> str:
    share = summary["share_found"]
    return "-" if share is None else f"{100.0 * share:.0f}%"
