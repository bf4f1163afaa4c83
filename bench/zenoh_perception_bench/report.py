"""The benches' text reports: their JSON reports as plain-text tables."""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Sequence
from typing import Any, Final

from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR
from zenoh_perception_bench.runners import BEST, BEST_SETTING, PAIR, SHOWN
from zenoh_perception_bench.scoring import BUCKETS

#: Columns a report line fits in (the dataset bench's).
REPORT_WIDTH: Final = 120


def table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Left-aligned columns under their headers and a rule."""
    widths = _widths(headers, rows)
    line = "  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True))
    out = [line, "  ".join("-" * w for w in widths)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(line.rstrip() for line in out)


def _widths(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> list[int]:
    return [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(headers)]


def narrow_table(
    headers: Sequence[str], rows: Sequence[Sequence[str]], width: int = REPORT_WIDTH
) -> str:
    """:func:`table` within ``width`` columns: split into tables that each repeat the first
    column, or, where one column alone is too wide, one row at a time, a column a line."""
    widths = _widths(headers, rows)
    if sum(widths) + 2 * (len(widths) - 1) <= width:
        return table(headers, rows)
    chunks: list[list[int]] = [[]]
    for i in range(1, len(headers)):
        if widths[0] + sum(widths[j] + 2 for j in [*chunks[-1], i]) > width and chunks[-1]:
            chunks.append([])
        chunks[-1].append(i)
    if all(widths[0] + sum(widths[j] + 2 for j in chunk) <= width for chunk in chunks):
        return "\n\n".join(
            table(
                [headers[0], *(headers[j] for j in chunk)],
                [[r[0], *(r[j] for j in chunk)] for r in rows],
            )
            for chunk in chunks
        )
    out: list[str] = []
    for row in rows:
        out += textwrap.wrap(row[0], width, subsequent_indent="    ") or ["-"]
        for header, cell in zip(headers[1:], row[1:], strict=True):
            out += textwrap.wrap(
                f"{header}: {cell}", width, initial_indent="  ", subsequent_indent="    "
            )
    return "\n".join(out)


def fit(text: str, width: int = REPORT_WIDTH) -> str:
    """``text`` with each line longer than ``width`` wrapped (prose: tables are narrowed)."""
    return "\n".join(
        line if len(line) <= width else textwrap.fill(line, width, subsequent_indent="  ")
        for line in text.splitlines()
    )


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


def best_setting_text() -> str:
    """OpenCV's best setting in a few words, for the reports' headers."""
    windows = (
        f"windows {BEST_SETTING['adaptiveThreshWinSizeMin']:g}-"
        f"{BEST_SETTING['adaptiveThreshWinSizeMax']:g} step "
        f"{BEST_SETTING['adaptiveThreshWinSizeStep']:g}"
    )
    return f"{windows}, min perimeter {BEST_SETTING['minMarkerPerimeterRate']:g}"


def _best_words() -> str:
    return f"OpenCV's best setting: {best_setting_text()}; shown, not judged"


# -- the generated bench ---------------------------------------------------------------------


def format_report(report: dict[str, Any]) -> str:
    """The generated bench's tables."""
    parts = [_detection(report)]
    if "e2e" in report:
        parts.append(_end_to_end(report))
    if "throughput" in report:
        parts.append(_throughput(report["throughput"]))
    if "boards" in report:
        parts.append(_boards(report["boards"]))
    if "range" in report:
        parts.append(_range(report["range"]))
    parts.append(goals_table(report["goals"], lambda v: fmt(v, ".3f")))
    return "\n\n".join(parts)


def _range(case: dict[str, Any]) -> str:
    """The range figure: per distance the share of frames each detector found the tag in."""
    shares = case["found_share"]
    names = list(shares)
    rows = [[f"{float(d):g} m", *(f"{shares[n][d]:.0%}" for n in names)] for d in shares[names[0]]]
    rows.append(["range (90 % of frames)", *(f"{case['range_m'][n]:g} m" for n in names)])
    title = (
        f"A {case['tag_m'] * 100:g} cm DICT_4X4_50 tag at each distance, {case['resolution']}, "
        f"{case['frames_per_distance']} frames each: share found"
    )
    if BEST in names:
        title += f" ({BEST} = {_best_words()})"
    return title + "\n" + table(["distance", *names], rows)


def _boards(case: dict[str, Any]) -> str:
    """The board case: per frame OpenCV's default and the service's ms and tags found, the
    totals, and a good frame's ms after the storm."""
    rows = [
        [
            row["kind"],
            str(row["square_px"]),
            *(fmt(row[name]["ms"], ".1f") for name in PAIR),
            *(f"{row[name]['found']}/{row[name]['tags']}" for name in PAIR),
        ]
        for row in case["frames"]
    ]
    summary = case["summary"]
    rows.append(
        [
            "median (found, false: totals)",
            "",
            *(fmt(summary[name]["median_ms"], ".1f") for name in PAIR),
            *(
                f"{summary[name]['found']}/{summary[name]['tags']}, {summary[name]['false']}"
                for name in PAIR
            ),
        ]
    )
    after = case["after_storm_ms"]
    rows.append(
        ["a good frame after the storm", "", *(fmt(after[name], ".1f") for name in PAIR), "", ""]
    )
    rows.append(
        [
            "plain frame: the grid keeper's cost",
            "",
            fmt(case["plain_frame_opencv_ms"], ".1f"),
            fmt(case["plain_frame_cost_ms"], ".4f"),
            "",
            "",
        ]
    )
    headers = ["board (HD720, left half)", "square px", *(f"{n} ms" for n in PAIR)]
    headers += [f"{n} tags" for n in PAIR]
    text = "Checkerboards beside tags, frame by frame\n" + table(headers, rows)
    paced = case.get("paced")
    if paced is not None:
        text += (
            f"\nThe same boards at {paced['rate_hz']:g} Hz into a service process, a plain frame "
            f"every fourth: {paced['answered']} of {paced['frames']} frames answered "
            f"({paced['answered_per_s']:.1f} a second); plain frames answered "
            f"{paced['plain_answered']} of {paced['plain_frames']}, receipt to tag median "
            f"{fmt(paced['plain_latency_median_ms'], '.1f')} ms, max "
            f"{fmt(paced['plain_latency_max_ms'], '.1f')} ms\n"
        )
    busy = case.get("busy")
    if busy is not None:
        text += (
            f"A board past the frame deadline (OpenCV's default {busy['opencv_ms']:.0f} ms a "
            f"frame) at {busy['rate_hz']:g} Hz: {busy['answered_with_tags']} of "
            f"{busy['frames']} frames answered with its tags "
            f"({busy['status_frames']['rejected']} abandoned)\n"
        )
    return text


def _detection(report: dict[str, Any]) -> str:
    rows = []
    for name, entry in report["sets"].items():
        for who in ("baseline", BEST, "tracking"):
            if who not in entry:  # a report made before OpenCV's best setting was run
                continue
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
    return (
        "Detection (BGRA frame in, tags out; same frames, one process, order rotating;"
        f" {BEST} = {_best_words()})\n" + table(headers, rows)
    )


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
    """The labelled-dataset bench's tables: OpenCV's default and the service side by side
    (``a/b`` is OpenCV's figure / the service's); in the totals and by dictionary OpenCV's
    best setting between them (``a/b/c``)."""
    parts = [_totals(report), _dictionaries(report), _sizes(report), _items(report)]
    hints = _hints(report)
    if hints:
        parts.append(hints)
    if report.get("refused"):
        parts.append(
            "Refused (over max_frame_pixels: not decoded, the service would refuse these frames)\n"
            + "\n".join(f"  {r['name']}: {r['reason']}" for r in report["refused"])
        )
    e2e = _dataset_end_to_end(report)
    if e2e:
        parts.append(e2e)
    parts.append(_dataset_goals(report["goals"]))
    return fit("\n\n".join(parts))


def _pct(summary: dict[str, Any]) -> str:
    share = summary["share_found"]
    return "-" if share is None else f"{100.0 * share:.1f}%"


def _side(report_row: dict[str, Any], key: str, names: Sequence[str] = PAIR) -> str:
    """The figures of ``names`` (default: OpenCV's / the service's), ``/`` between."""
    return "/".join(str(report_row[who][key]) for who in names)


def _ids(counts: dict[str, int]) -> str:
    """``{"7": 2, "3": 1}`` as ``ids 3, 7x2``; ``-`` for none."""
    if not counts:
        return "-"
    shown = [
        k if n == 1 else f"{k}x{n}" for k, n in sorted(counts.items(), key=lambda e: int(e[0]))
    ]
    return "ids " + ", ".join(shown[:6]) + (", ..." if len(shown) > 6 else "")


def _side_headers(names: Sequence[str] = PAIR) -> list[str]:
    """The headers of :func:`_side_cells`: ``o/s``, or ``o/b/s`` with OpenCV's best setting."""
    letters = "/".join(who[0] for who in names)
    return [f"{what} {letters}" for what in ("found", "share", "false", "unverified", "ms")]


def _side_cells(row: dict[str, Any], names: Sequence[str] = PAIR) -> list[str]:
    return [
        _side(row, "found", names),
        "/".join(_pct(row[who]) for who in names),
        _side(row, "false_ids", names),
        _side(row, "unverified", names),
        "/".join(fmt(row[who]["mean_ms"]) for who in names),
    ]


def _shown(group: dict[str, Any]) -> tuple[str, ...]:
    """The detectors a report's group has: :data:`SHOWN`, or :data:`PAIR` in a report made
    before OpenCV's best setting was run."""
    return SHOWN if BEST in group else PAIR


def _totals(report: dict[str, Any]) -> str:
    rows = []
    groups = {**report["groups"], "all": report["all"]}
    names = _shown(report["all"])
    for name, group in groups.items():
        if group["opencv"]["frames"] == 0:
            continue
        rows.append(
            [
                name,
                str(group["opencv"]["frames"]),
                str(group["opencv"]["labelled"]),
                *_side_cells(group, names),
            ]
        )
    legend = (
        f"o/b/s = OpenCV default / OpenCV's best setting ({best_setting_text()}; shown, not"
        " judged) / service"
        if names == SHOWN
        else "o/s = OpenCV default / service"
    )
    return (
        f"Totals ({legend}; found = labelled markers reported, on video"
        " id-frames; false = ids the labels do not hold; unverified = ids of markers seen but"
        " not read; ms = mean per frame)\n"
        + narrow_table(["group", "frames", "labelled", *_side_headers(names)], rows)
    )


def _dictionaries(report: dict[str, Any]) -> str:
    names = _shown(report["all"])
    rows = [
        [name, str(d["opencv"]["frames"]), str(d["opencv"]["labelled"]), *_side_cells(d, names)]
        for name, d in report["dictionaries"].items()
    ]
    legend = "; o/b/s as in the totals" if names == SHOWN else ""
    return f"By dictionary (every item read in it, negatives included{legend})\n" + narrow_table(
        ["dictionary", "frames", "labelled", *_side_headers(names)], rows
    )


def _sizes(report: dict[str, Any]) -> str:
    stills = report["groups"]["stills"]
    videos = report["groups"]["videos"]
    every = report["all"]
    rows = [
        [
            bucket,
            f"{stills['opencv']['buckets'][bucket]}/{stills['service']['buckets'][bucket]}",
            f"{videos['opencv']['buckets'][bucket]}/{videos['service']['buckets'][bucket]}",
            f"{every['opencv']['false_buckets'][bucket]}/{every['service']['false_buckets'][bucket]}",
        ]
        for bucket in BUCKETS
    ]
    return "By marker size (mean side; o/s = OpenCV default / service)\n" + narrow_table(
        ["size", "stills found o/s", "video id-frames found o/s", "false ids o/s (all)"], rows
    )


def negatives_merged(items: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The items, each negative's rows (one per dictionary it was read in) as one."""
    out: list[dict[str, Any]] = []
    merged: dict[str, dict[str, Any]] = {}
    for item in items:
        if not item["negative"]:
            out.append(item)
            continue
        names = _shown(item)
        if item["name"] not in merged:
            merged[item["name"]] = {**item, "dictionaries": 0, "times": {w: [] for w in names}}
            merged[item["name"]].update({w: dict(item[w]) for w in names})
            out.append(merged[item["name"]])
            for who in names:
                merged[item["name"]][who]["false_examples"] = {}
                for key in ("false_ids", "unverified"):
                    merged[item["name"]][who][key] = 0
        entry = merged[item["name"]]
        entry["dictionaries"] += 1
        entry["dictionary"] = f"{entry['dictionaries']} dictionaries"
        for who in names:
            into, row = entry[who], item[who]
            into["false_ids"] += row["false_ids"]
            into["unverified"] += row["unverified"]
            examples = into["false_examples"]
            for tag, n in row["false_examples"].items():
                examples[tag] = examples.get(tag, 0) + n
            if row["mean_ms"] is not None:
                entry["times"][who].append(row["mean_ms"])
            times = entry["times"][who]
            into["mean_ms"] = sum(times) / len(times) if times else None
    return out


def _items(report: dict[str, Any]) -> str:
    rows = []
    for item in negatives_merged(report["items"]):
        label = item["name"] + (" (unsure)" if item["unsure"] else "")
        if item["negative"]:
            label += " (negative)"
        rows.append(
            [
                label,
                item["kind"],
                item["dictionary"],
                f"{item['size'][0]}x{item['size'][1]}",
                str(item["opencv"]["frames"]),
                str(item["opencv"]["labelled"]),
                *_side_cells(item),
                _ids(item["service"]["missed"]),
                _ids(item["opencv"]["false_examples"]),
                _ids(item["service"]["false_examples"]),
            ]
        )
    headers = [
        "item",
        "kind",
        "dictionary",
        "size",
        "frames",
        "labelled",
        *_side_headers(),
        "missed (service)",
        "unexpected (opencv)",
        "unexpected (service)",
    ]
    return (
        "Items (o/s = OpenCV default / service; a negative in one row over every dictionary"
        " it was read in, frames per dictionary)\n" + narrow_table(headers, rows)
    )


def _hints(report: dict[str, Any]) -> str | None:
    lines = [
        f"  {item['name']} ({item['dictionary']}): {item['hint']}"
        for item in report["items"]
        if item.get("hint")
    ]
    if not lines:
        return None
    return (
        "Nothing found (OpenCV's default tried the other families and the flipped picture on"
        " the first frame)\n" + "\n".join(lines)
    )


def _dataset_goals(goals: Sequence[dict[str, Any]]) -> str:
    """One line per goal (result, goal, value, threshold), then its figures against the
    labels and its note, each on a line of its own: the rows fit the report's width."""
    lines = ["Goals (against OpenCV's default, and the same figures against the labels)"]
    for g in goals:
        result = "PASS" if g["pass"] else "FAIL"
        lines.append(f"{result}  {g['goal']}: {g['value']} ({g['threshold']})")
        lines += [f"      {text}" for text in (g.get("labels", ""), g["note"]) if text]
    return "\n".join(lines)


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
        + narrow_table(headers, rows)
    )
