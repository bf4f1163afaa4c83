"""The benches' goals: each with its measured value, threshold and PASS / FAIL.

A bench exits 1 when one fails. On generated frames (:func:`goals`): on every set the service's
detector finds at least what OpenCV's default finds with no more false ids, its median centre
error stays under :data:`CENTRE_ERROR_PX`, and end to end a service's own cost (end to end minus
the transport floor) against OpenCV's bare detection time stays under
:data:`VIDEO_E2E_RATIO` (means, on video) or :data:`INDEPENDENT_E2E_RATIO` (medians, on
independent frames); a service keeps up with HD1080 at 60 Hz.

On labelled pictures and videos (:func:`dataset_goals`): on the stills in total, per
dictionary and per size bucket, and on every video, the service finds at least what OpenCV's
default finds; it reports no false id on the negatives and no more false ids than OpenCV
elsewhere; end to end, its mean own cost on the videos stays under :data:`VIDEO_E2E_RATIO`.
"""

from __future__ import annotations

import math
from typing import Any, Final

from zenoh_perception.bench.framesets import VIDEO_RESOLUTION
from zenoh_perception.bench.processes import E2E_DETECTORS, FLOOR
from zenoh_perception.bench.scoring import BUCKETS, rounded

#: A service's own cost on video (mean, end to end - floor) / OpenCV's mean detection time.
VIDEO_E2E_RATIO: Final = 0.5
#: The same on independent frames, with medians.
INDEPENDENT_E2E_RATIO: Final = 1.0
#: The median centre error of what the service's detector finds, worst generated set.
CENTRE_ERROR_PX: Final = 0.5


def goal(name: str, value: Any, threshold: str, passed: bool, note: str = "") -> dict[str, Any]:
    """One goal's row of a report."""
    return {
        "goal": name,
        "value": value,
        "threshold": threshold,
        "pass": bool(passed),
        "note": note,
    }


def own_cost_ms(entry: dict[str, Any], who: str, stat: str) -> float:
    """A service's own cost in an end-to-end entry: its ``stat`` (``median_ms`` or
    ``mean_ms``) end to end minus the transport floor's."""
    return float(entry[who][stat]) - float(entry[FLOOR][stat])


def goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Every goal of the generated bench (its report without ``goals``)."""
    sets = report["sets"]
    rows: list[dict[str, Any]] = []

    def add(name: str, value: float | None, limit: str, passed: bool, note: str = "") -> None:
        rows.append(goal(name, None if value is None else rounded(value), limit, passed, note))

    for name, entry in sets.items():
        found, base = entry["tracking"]["found"], entry["baseline"]["found"]
        add(f"{name}: tags found >= OpenCV default", found, f">= {base}", found >= base)
        fp, base_fp = entry["tracking"]["false_positives"], entry["baseline"]["false_positives"]
        add(f"{name}: false ids <= OpenCV default", fp, f"<= {base_fp}", fp <= base_fp)
    errors = [s["tracking"]["centre_error_px"] for s in sets.values()]
    worst = max((e for e in errors if e is not None), default=math.inf)
    add(
        "median centre error, worst set (px)",
        worst,
        f"<= {CENTRE_ERROR_PX}",
        worst <= CENTRE_ERROR_PX,
    )
    e2e = report.get("e2e")
    if e2e is not None:
        for set_name, stat, limit in (
            ("video", "mean_ms", VIDEO_E2E_RATIO),
            ("real-camera video", "mean_ms", VIDEO_E2E_RATIO),
            (VIDEO_RESOLUTION, "median_ms", INDEPENDENT_E2E_RATIO),
        ):
            entry = e2e[set_name]
            bare = entry["baseline_detection"][stat]
            own = own_cost_ms(entry, "tracking", stat)
            word = stat.removesuffix("_ms")
            add(
                f"{set_name}: service {word} e2e - floor / OpenCV {word} detection",
                own / bare,
                f"<= {limit}",
                own / bare <= limit,
                f"{own:.2f} ms vs {bare:.2f} ms; raw e2e {entry['tracking'][stat]:.2f} ms, "
                f"floor {entry[FLOOR][stat]:.2f} ms; {_passes_note(entry)}",
            )
            found = entry["tracking"]["found"]
            base = sets[set_name]["baseline"]["found"] * entry["passes"]
            add(
                f"{set_name}: tags found by the service (records) >= OpenCV default",
                found,
                f">= {base}",
                found >= base,
            )
    throughput_report = report.get("throughput")
    if throughput_report is not None:
        default = throughput_report["tracking"]
        add(
            "HD1080 at 60 Hz: every frame processed",
            default["processed"],
            f"== {default['published']} published, 0 dropped",
            default["processed"] == default["published"] and default["dropped"] == 0,
            f"dropped {default['dropped']}, {default['processed_hz']:.1f} Hz",
        )
    if "lookalikes" in report:
        rows += lookalike_goals(report["lookalikes"])
    return rows


def _passes_note(entry: dict[str, Any]) -> str:
    if entry["passes"] == 1:
        return "one pass"
    each = ", ".join(f"{r:.2f}" for r in entry["pass_ratios"]["tracking"])
    return f"{entry['passes']} passes pooled, own-cost ratio of each: {each}"


def dataset_goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Every goal of the labelled-dataset bench (its report without ``goals``)."""
    rows: list[dict[str, Any]] = []
    groups = report["groups"]
    for name, group in groups.items():
        if name == "negatives" or group["service"]["frames"] == 0:
            continue
        found, base = group["service"]["found"], group["opencv"]["found"]
        rows.append(goal(f"{name}: found >= OpenCV default", found, f">= {base}", found >= base))
        if name == "stills":
            for bucket in BUCKETS:
                found = group["service"]["buckets"][bucket]
                base = group["opencv"]["buckets"][bucket]
                rows.append(
                    goal(
                        f"stills {bucket}: found >= OpenCV default",
                        found,
                        f">= {base}",
                        found >= base,
                    )
                )
        if name in ("stills", "videos"):
            fp, base_fp = group["service"]["false_ids"], group["opencv"]["false_ids"]
            rows.append(
                goal(f"{name}: false ids <= OpenCV default", fp, f"<= {base_fp}", fp <= base_fp)
            )
    if groups["negatives"]["service"]["frames"]:
        fp = groups["negatives"]["service"]["false_ids"]
        base_fp = groups["negatives"]["opencv"]["false_ids"]
        rows.append(goal("negatives: false ids", fp, "== 0", fp == 0, f"OpenCV default: {base_fp}"))
    chosen = report["settings"]["detector"]
    own: dict[str, float] = dict.fromkeys(E2E_DETECTORS, 0.0)
    bare = 0.0
    for item in report["items"]:
        if item["kind"] == "image" or item["negative"]:
            continue
        found, base = item["service"]["found"], item["opencv"]["found"]
        rows.append(
            goal(
                f"video {item['name']}: found >= OpenCV default", found, f">= {base}", found >= base
            )
        )
        e2e = item.get("e2e")
        if e2e is None:
            continue
        frames = item["service"]["frames"]
        for name in E2E_DETECTORS:
            own[name] += own_cost_ms(e2e, name, "mean_ms") * frames
        bare += e2e["opencv_detection"]["mean_ms"] * frames
        found = e2e[chosen]["found"]
        rows.append(
            goal(
                f"video {item['name']}: found by the service process >= OpenCV default",
                found,
                f">= {base}",
                found >= base,
            )
        )
    if bare > 0.0:
        ratio = own[chosen] / bare
        others = ", ".join(
            f"detector={name}: {own[name] / bare:.3f}" for name in own if name != chosen
        )
        rows.append(
            goal(
                f"videos: service (detector={chosen}) mean e2e - floor / OpenCV mean detection",
                round(ratio, 3),
                f"<= {VIDEO_E2E_RATIO}",
                ratio <= VIDEO_E2E_RATIO,
                f"frame-weighted over the videos; {others}",
            )
        )
    return rows


def lookalike_goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The generated look-alike sets (:mod:`~zenoh_perception.bench.lookalikes`): per family,
    the service reports no false id and finds every true tag OpenCV's default finds."""
    rows: list[dict[str, Any]] = []
    for family, row in report.items():
        false_ids = row["service"]["false_ids"]
        note = f"OpenCV default: {row['opencv']['false_ids']}"
        rows.append(
            goal(f"look-alikes {family}: false ids", false_ids, "== 0", false_ids == 0, note)
        )
        found, base = row["service"]["true_found"], row["opencv"]["true_found"]
        rows.append(
            goal(
                f"look-alikes {family}: true tags >= OpenCV default",
                found,
                f">= {base}",
                found >= base,
            )
        )
    return rows
