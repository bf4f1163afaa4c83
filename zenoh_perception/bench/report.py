"""The benches' text reports: their JSON reports as plain-text tables."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from zenoh_perception.bench.processes import E2E_DETECTORS, FLOOR
from zenoh_perception.bench.runners import PAIR
from zenoh_perception.bench.scoring import BUCKETS


def table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Left-aligned columns under their headers and a rule."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(out)


def fmt(value: Any, spec: str = ".2f") -> str:
    """A figure of a table: ``-`` for none, floats to ``spec``."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return format(value, spec)
    return str(value)


def goals_table(goals: Sequence[dict[str, Any]], value: Callable[[Any], str]) -> str:
    """The goals, each with its ``value`` written, threshold and PASS / FAIL."""
    rows = [
        [g["goal"], value(g["value"]), g["threshold"], "PASS" if g["pass"] else "FAIL", g["note"]]
        for g in goals
    ]
    return "Goals\n" + table(["goal", "value", "threshold", "result", "note"], rows)


# -- the generated bench ---------------------------------------------------------------------


def format_report(report: dict[str, Any]) -> str:
    """The generated bench's tables."""
    parts = [_detection(report)]
    if "e2e" in report:
        parts.append(_end_to_end(report))
    if "throughput" in report:
        parts.append(_throughput(report["throughput"]))
    parts.append(goals_table(report["goals"], lambda v: fmt(v, ".3f")))
    return "\n\n".join(parts)


def _detection(report: dict[str, Any]) -> str:
    rows = []
    for name, entry in report["sets"].items():
        for who in ("baseline", "tracking"):
            s = entry[who]
            rows.append(
                [
                    name,
                    who,
                    fmt(s["median_ms"]),
                    fmt(s["p99_ms"]),
                    fmt(s["mean_ms"]),
                    f"{s['recall']:.3f} ({s['found']}/{s['visible']})",
                    str(s["false_positives"]),
                    fmt(s["centre_error_px"], ".3f"),
                    fmt(s["distance_error_pct"], ".2f"),
                ]
            )
    headers = [
        "set",
        "detector",
        "median ms",
        "p99 ms",
        "mean ms",
        "recall",
        "FP",
        "centre px",
        "dist err %",
    ]
    return "Detection (BGRA frame in, tags out; same frames, one process)\n" + table(headers, rows)


def _end_to_end(report: dict[str, Any]) -> str:
    rows = []
    pass_lines = []
    for set_name, entry in report["e2e"].items():
        name = set_name if entry["passes"] == 1 else f"{set_name} x{entry['passes']}"
        if entry["passes"] > 1:
            each = "; ".join(
                f"{who} " + ", ".join(f"{r:.2f}" for r in entry["pass_ratios"][who])
                for who in E2E_DETECTORS
            )
            stat = "mean" if report["sets"][set_name]["video"] else "median"
            pass_lines.append(
                f"\n{set_name}: {entry['passes']} passes over its frames, each with fresh"
                f" service processes, pooled above; {stat} own cost (e2e - floor) / bare"
                f" {stat} per pass: {each}"
            )
        bare = entry["baseline_detection"]
        rows.append(
            [
                name,
                "bare baseline",
                fmt(bare["median_ms"]),
                fmt(bare["mean_ms"]),
                fmt(bare["p99_ms"]),
                "-",
                "-",
                "-",
                "-",
                "-",
            ]
        )
        for who in (*E2E_DETECTORS, FLOOR):
            s = entry[who]
            rows.append(
                [
                    name,
                    f"service {who}",
                    fmt(s["median_ms"]),
                    fmt(s["mean_ms"]),
                    fmt(s["p99_ms"]),
                    fmt(s["detect_median_ms"]),
                    fmt(s["overhead_median_ms"]),
                    fmt(s["overhead_mean_ms"]),
                    f"{s['recall']:.3f}",
                    str(s["false_positives"]),
                ]
            )
    setup = report.get("e2e_setup", {})
    note = f"; camera put: {setup['camera_put']}" if "camera_put" in setup else ""
    if setup.get("shm_fallback"):
        note += f" (shared memory unavailable: {setup['shm_fallback']})"
    headers = [
        "frames",
        "detector",
        "median ms",
        "mean ms",
        "p99 ms",
        "detect med",
        "overhead med",
        "overhead mean",
        "recall",
        "FP",
    ]
    return (
        "End to end through the service (put -> tag, lockstep; each service is its own"
        " `zenoh-perception run` process, Zenoh peers over loopback; the bare baseline ran"
        f" on each frame in turn with the services{note}; overhead = e2e - the service's"
        " detect_ms)\n" + table(headers, rows) + "".join(pass_lines)
    )


def _throughput(runs: dict[str, Any]) -> str:
    rows = [
        [
            who,
            t["resolution"],
            f"{t['rate_hz']:.0f}",
            str(t["published"]),
            str(t["processed"]),
            str(t["dropped"]),
            f"{t['processed_hz']:.1f}",
            fmt(t["latency_p50_ms"]),
            fmt(t["latency_p99_ms"]),
        ]
        for who, t in runs.items()
    ]
    headers = [
        "detector",
        "size",
        "Hz",
        "published",
        "processed",
        "dropped",
        "proc Hz",
        "lat p50",
        "lat p99",
    ]
    return (
        "Throughput (frames published at a fixed rate to a service process; latency ="
        " receive -> publish in the service)\n" + table(headers, rows)
    )


# -- the labelled-dataset bench --------------------------------------------------------------


def format_dataset_report(report: dict[str, Any]) -> str:
    """The labelled-dataset bench's tables."""
    parts = [_totals(report), _sizes(report), _items(report)]
    e2e = _dataset_end_to_end(report)
    if e2e:
        parts.append(e2e)
    parts.append(goals_table(report["goals"], str))
    return "\n\n".join(parts)


def _totals(report: dict[str, Any]) -> str:
    headers = ["group", "frames", "labelled"]
    for who in PAIR:
        headers += [f"{who} found", f"{who} false", f"{who} med ms", f"{who} mean ms"]
    rows = []
    for name, group in report["groups"].items():
        row = [name, str(group["opencv"]["frames"]), str(group["opencv"]["labelled"])]
        for who in PAIR:
            s = group[who]
            row += [str(s["found"]), str(s["false_ids"]), fmt(s["median_ms"]), fmt(s["mean_ms"])]
        rows.append(row)
    return "Totals (found = labelled markers reported; on video, id-frames)\n" + table(
        headers, rows
    )


def _sizes(report: dict[str, Any]) -> str:
    stills = report["groups"]["stills"]
    rows = [
        [
            bucket,
            str(stills["opencv"]["buckets"][bucket]),
            str(stills["service"]["buckets"][bucket]),
        ]
        for bucket in BUCKETS
    ]
    return "Stills by marker size (mean side)\n" + table(
        ["size", "opencv found", "service found"], rows
    )


def _items(report: dict[str, Any]) -> str:
    rows = []
    for item in report["items"]:
        row = [
            item["name"] + (" (unsure)" if item["unsure"] else ""),
            item["kind"],
            item["dictionary"],
            f"{item['size'][0]}x{item['size'][1]}",
            str(item["opencv"]["frames"]),
            str(item["opencv"]["labelled"]),
        ]
        for who in PAIR:
            s = item[who]
            row += [f"{s['found']}/{s['false_ids']}", fmt(s["mean_ms"])]
        rows.append(row)
    headers = [
        "item",
        "kind",
        "dictionary",
        "size",
        "frames",
        "labelled",
        "opencv",
        "ms",
        "service",
        "ms",
    ]
    return "Items (found/false ids, mean ms per frame)\n" + table(headers, rows)


def _dataset_end_to_end(report: dict[str, Any]) -> str | None:
    rows = []
    for item in report["items"]:
        e2e = item.get("e2e")
        if e2e is None:
            continue
        bare = e2e["opencv_detection"]["mean_ms"]
        floor = e2e[FLOOR]["mean_ms"]
        for name in (*E2E_DETECTORS, FLOOR):
            s = e2e[name]
            own = s["mean_ms"] - floor
            rows.append(
                [
                    item["name"],
                    name,
                    fmt(s["median_ms"]),
                    fmt(s["mean_ms"]),
                    "-" if name == FLOOR else fmt(own),
                    "-" if name == FLOOR else f"{own / bare:.2f}",
                    fmt(bare),
                    str(s["found"]),
                ]
            )
    if not rows:
        return None
    headers = [
        "video",
        "process",
        "med ms",
        "mean ms",
        "own ms",
        "own / opencv",
        "opencv ms",
        "found",
    ]
    return (
        "Videos end to end (lockstep through service processes; own = mean e2e - floor)\n"
        + table(headers, rows)
    )
