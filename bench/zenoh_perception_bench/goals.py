"""The benches' goals: each with its measured value, threshold and PASS / FAIL.

A bench exits 1 when one fails. On generated frames (:func:`goals`): on every set the service's
detector finds at least what OpenCV's default finds with no more false ids, its median centre
error stays under :data:`CENTRE_ERROR_PX`, and end to end a service's own cost (end to end minus
the transport floor) against OpenCV's bare detection time stays under
:data:`VIDEO_E2E_RATIO` (means, on video) or :data:`INDEPENDENT_E2E_RATIO` (medians, on
independent frames); a service keeps up with HD1080 at 60 Hz.

On labelled pictures and videos (:func:`dataset_goals`): on every item the service finds
every tag (id by id) that OpenCV's default finds, and so on the stills in total, per
dictionary and per size bucket, and on every video; it reports no false id on the negatives,
no unlabelled id on the positives whose labels are sure, and no more false ids than OpenCV
anywhere (a false id OpenCV reports and the service does not is a win); end to end, its mean
own cost on the videos stays under :data:`VIDEO_E2E_RATIO`. Each goal also states its figures
against the labels (found / labelled).
"""

from __future__ import annotations

import math
from typing import Any, Final

from zenoh_perception_bench.framesets import VIDEO_RESOLUTION
from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR
from zenoh_perception_bench.scoring import BUCKETS, rounded

#: A service's own cost on video (mean, end to end - floor) / OpenCV's mean detection time.
VIDEO_E2E_RATIO: Final = 0.5
#: The same on independent frames, with medians.
INDEPENDENT_E2E_RATIO: Final = 1.0
#: The median centre error of what the service's detector finds, worst generated set.
CENTRE_ERROR_PX: Final = 0.5


#: The service's range over OpenCV default's (bench.reach).
RANGE_RATIO: Final = 1.3
#: A frame with a checkerboard over half of it, answered within this (median, ms).
BOARD_MEDIAN_MS: Final = 60.0
#: What looking out for grids may add to a plain frame (ms).
PLAIN_FRAME_COST_MS: Final = 0.1


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
    boards = report.get("boards")
    if boards is not None:
        summary = boards["summary"]
        service, opencv = summary["service"], summary["opencv"]
        add(
            "boards: service median ms a frame",
            service["median_ms"],
            f"<= {BOARD_MEDIAN_MS}",
            service["median_ms"] <= BOARD_MEDIAN_MS,
            f"OpenCV default {opencv['median_ms']:.1f} ms",
        )
        add(
            "boards: tags found >= OpenCV default",
            service["found"],
            f">= {opencv['found']}",
            service["found"] >= opencv["found"],
        )
        add(
            "boards: false ids <= OpenCV default",
            service["false"],
            f"<= {opencv['false']}",
            service["false"] <= opencv["false"],
        )
        after = boards["after_storm_ms"]["service"]
        add(
            "boards: a good frame after the storm (ms)",
            after,
            f"<= {BOARD_MEDIAN_MS}",
            after <= BOARD_MEDIAN_MS,
            f"OpenCV default {boards['after_storm_ms']['opencv']:.1f} ms",
        )
        cost = boards["plain_frame_cost_ms"]
        add(
            "boards: the grid keeper's cost on a plain frame (ms)",
            cost,
            f"<= {PLAIN_FRAME_COST_MS}",
            cost <= PLAIN_FRAME_COST_MS,
            f"OpenCV default {boards['plain_frame_opencv_ms']:.1f} ms on it",
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
    if "range" in report:
        reached = report["range"]["range_m"]
        service, opencv = reached["service"], reached["opencv"]
        add(
            "range: a 20 cm tag found in 90 % of HD720 frames (m)",
            service,
            f">= {RANGE_RATIO} x {opencv:g}",
            service >= RANGE_RATIO * opencv,
            f"OpenCV default {opencv:g} m",
        )
    return rows


def _passes_note(entry: dict[str, Any]) -> str:
    if entry["passes"] == 1:
        return "one pass"
    each = ", ".join(f"{r:.2f}" for r in entry["pass_ratios"]["tracking"])
    return f"{entry['passes']} passes pooled, own-cost ratio of each: {each}"


def _labels(summary: dict[str, Any]) -> str:
    """Found / labelled, and the share, of a summary."""
    share = summary["share_found"]
    pct = "-" if share is None else f"{100.0 * share:.1f} %"
    return f"{summary['found']}/{summary['labelled']} ({pct})"


def lost_tags(item: dict[str, Any]) -> dict[str, int]:
    """Id -> markers (id-frames on video) of an item OpenCV's default found and the service
    did not."""
    opencv, service = item["opencv"]["found_ids"], item["service"]["found_ids"]
    return {tag: n - service.get(tag, 0) for tag, n in opencv.items() if n > service.get(tag, 0)}


def _listed(entries: list[str]) -> str:
    return ", ".join(entries[:8]) + (f" and {len(entries) - 8} more" if len(entries) > 8 else "")


def _false_goal(name: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The service reports no false id on ``rows``; OpenCV's count stated beside."""
    service = sum(r["service"]["false_ids"] for r in rows)
    opencv = sum(r["opencv"]["false_ids"] for r in rows)
    where = [
        f"{r['name']} {r['dictionary']} ({r['opencv']['false_ids']}/{r['service']['false_ids']})"
        for r in rows
        if r["service"]["false_ids"]
    ]
    note = f"OpenCV/service false: {opencv}/{service}"
    if where:
        note += f"; service false on {_listed(where)}"
    row = goal(name, service, "== 0", service == 0, note)
    row["labels"] = f"every id reported there is false; OpenCV default: {opencv}"
    return row


def dataset_goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Every goal of the labelled-dataset bench (its report without ``goals``); each row's
    ``labels`` states the same figures against the labels."""
    rows: list[dict[str, Any]] = []
    groups = report["groups"]
    items = report["items"]

    def add(row: dict[str, Any], labels: str) -> None:
        row["labels"] = labels
        rows.append(row)

    def both(summaries: dict[str, Any]) -> str:
        return f"service {_labels(summaries['service'])}, OpenCV {_labels(summaries['opencv'])}"

    # against OpenCV on every item: no tag OpenCV finds is lost
    lost = {f"{i['name']}": lost_tags(i) for i in items if not i["negative"]}
    lost_count = sum(sum(ids.values()) for ids in lost.values())
    where = [f"{name} id {', '.join(ids)}" for name, ids in lost.items() if ids]
    positives = [i for i in items if not i["negative"]]
    total = {
        who: {
            "found": sum(i[who]["found"] for i in positives),
            "labelled": sum(i[who]["labelled"] for i in positives),
        }
        for who in ("service", "opencv")
    }
    for t in total.values():
        t["share_found"] = t["found"] / t["labelled"] if t["labelled"] else None
    if positives:
        add(
            goal(
                "every tag OpenCV default finds, the service finds (per item and id)",
                lost_count,
                "== 0",
                lost_count == 0,
                f"lost on {_listed(where)}" if where else "",
            ),
            both(total),
        )
        labels_row = _labels_goal(positives)
        if labels_row is not None:
            rows.append(labels_row)
    # against the labels: no false id where the labels are sure
    negatives = [i for i in items if i["negative"]]
    if negatives:
        rows.append(_false_goal("negatives: false ids (service)", negatives))
    sure = [i for i in positives if not i["unsure"]]
    if sure:
        rows.append(_false_goal("sure positives: unlabelled ids (service)", sure))
    for name, group in groups.items():
        if name == "negatives" or group["service"]["frames"] == 0:
            continue
        found, base = group["service"]["found"], group["opencv"]["found"]
        add(
            goal(f"{name}: found >= OpenCV default", found, f">= {base}", found >= base),
            both(group),
        )
        if name == "stills":
            for bucket in BUCKETS:
                found = group["service"]["buckets"][bucket]
                base = group["opencv"]["buckets"][bucket]
                if found == base == 0:
                    continue  # no marker of this size: nothing to pass on
                add(
                    goal(
                        f"stills {bucket}: found >= OpenCV default",
                        found,
                        f">= {base}",
                        found >= base,
                    ),
                    "labels hold no size: found markers only",
                )
        if name in ("stills", "videos"):
            fp, base_fp = group["service"]["false_ids"], group["opencv"]["false_ids"]
            add(
                goal(
                    f"{name}: false ids <= OpenCV default",
                    fp,
                    f"<= {base_fp}",
                    fp <= base_fp,
                    f"OpenCV/service false: {base_fp}/{fp}",
                ),
                f"unverified (unreadable markers' ids): service {group['service']['unverified']},"
                f" OpenCV {group['opencv']['unverified']}",
            )
    chosen = report["settings"]["detector"]
    own: dict[str, float] = dict.fromkeys(E2E_DETECTORS, 0.0)
    bare = 0.0
    for item in items:
        if item["kind"] == "image" or item["negative"]:
            continue
        found, base = item["service"]["found"], item["opencv"]["found"]
        add(
            goal(
                f"video {item['name']}: found >= OpenCV default", found, f">= {base}", found >= base
            ),
            both(item),
        )
        e2e = item.get("e2e")
        if e2e is None:
            continue
        frames = item["service"]["frames"]
        for name in E2E_DETECTORS:
            own[name] += own_cost_ms(e2e, name, "mean_ms") * frames
        bare += e2e["opencv_detection"]["mean_ms"] * frames
        found = e2e[chosen]["found"]
        add(
            goal(
                f"video {item['name']}: found by the service process >= OpenCV default",
                found,
                f">= {base}",
                found >= base,
            ),
            f"service process {found}/{item['service']['labelled']} labelled id-frames",
        )
    if bare > 0.0:
        ratio = own[chosen] / bare
        others = ", ".join(
            f"detector={name}: {own[name] / bare:.3f}" for name in own if name != chosen
        )
        add(
            goal(
                f"videos: service (detector={chosen}) mean e2e - floor / OpenCV mean detection",
                round(ratio, 3),
                f"<= {VIDEO_E2E_RATIO}",
                ratio <= VIDEO_E2E_RATIO,
                f"frame-weighted over the videos; {others}",
            ),
            "-",
        )
    return rows


#: The share of the labelled markers some detector must find for the labels to be believed.
LABELS_FOUND_SHARE: Final = 0.5
#: What a run in which most labelled markers are found by no detector says.
LABELS_WRONG: Final = (
    "most labelled markers are found by no detector: the labels or the dictionary are "
    "probably wrong (zenoh-perception probe names the dictionary)"
)


def _labels_goal(positives: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Whether the detector that finds most finds most of the labelled markers (None with no
    labelled marker): when none does, the labels are the likelier fault."""
    labelled = sum(i["service"]["labelled"] for i in positives)
    if not labelled:
        return None
    who = [
        w for w in positives[0] if isinstance(positives[0][w], dict) and "found" in positives[0][w]
    ]
    best = max(sum(i[w]["found"] for i in positives) for w in who)
    share = best / labelled
    row = goal(
        "labelled markers found by the detector that finds most (share)",
        rounded(share, 3),
        f">= {LABELS_FOUND_SHARE}",
        share >= LABELS_FOUND_SHARE,
        "" if share >= LABELS_FOUND_SHARE else LABELS_WRONG,
    )
    row["labels"] = f"{best}/{labelled} labelled markers"
    return row


def lookalike_goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The generated look-alike sets (:mod:`~zenoh_perception_bench.lookalikes`): per family,
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
