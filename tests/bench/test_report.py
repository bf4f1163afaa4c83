"""The text reports: every figure of the JSON report stands in its row."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from tests.bench.conftest import BenchRun
from zenoh_perception.settings import Settings
from zenoh_perception_bench.dataset import evaluate
from zenoh_perception_bench.manifest import load_manifest
from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR
from zenoh_perception_bench.report import (
    fmt,
    format_dataset_report,
    format_report,
    narrow_table,
    table,
)
from zenoh_perception_bench.runners import BEST, PAIR, SHOWN
from zenoh_perception_bench.scoring import size_bucket


def rows(text: str) -> list[list[str]]:
    """Every line of ``text`` as its cells (columns are two spaces apart or more)."""
    return [re.split(r" {2,}", line.strip()) for line in text.splitlines() if line.strip()]


def row(text: str, *first: str) -> list[str]:
    """The one row whose first cells are ``first``."""
    found = [r for r in rows(text) if r[: len(first)] == list(first)]
    assert len(found) == 1, (first, found)
    return found[0]


def joined(text: str, *first: str) -> list[str]:
    """The row whose first cells are ``first``, its cells gathered from each part of a table
    split to fit the width (each part repeats the first cell)."""
    found = [r for r in rows(text) if r[0] == first[0]]
    assert found and found[0][: len(first)] == list(first), (first, found)
    return [*found[0], *(cell for part in found[1:] for cell in part[1:])]


def per_pass(name: str) -> re.Pattern[str]:
    """The line that gives each pass's figures of an end-to-end set."""
    return re.compile(rf"{re.escape(name)}: \d+ passes over its frames")


def test_table_aligns_columns_under_a_rule() -> None:
    text = table(["a", "long header"], [["wide cell", "x"], ["y", "z"]])
    assert text.splitlines() == [
        "a          long header",
        "---------  -----------",
        "wide cell  x",
        "y          z",
    ]


def test_a_wide_table_splits_repeating_its_first_column_or_goes_a_column_a_line() -> None:
    headers = ["name", *(f"column {i}" for i in range(6))]
    rows_ = [["first", *("x" * 30 for _ in range(6))]]
    text = narrow_table(headers, rows_, width=80)
    assert max(len(line) for line in text.splitlines()) <= 80
    assert joined(text, "first")[1:] == rows_[0][1:]
    one_wide = narrow_table(["name", "note"], [["first", "y" * 100]], width=80)
    assert one_wide.splitlines()[:2] == ["first", "  note: " + "y" * 72]


@pytest.mark.parametrize(
    ("value", "spec", "text"), [(None, ".2f", "-"), (1.23456, ".3f", "1.235"), (7, ".2f", "7")]
)
def test_fmt_writes_figures(value: Any, spec: str, text: str) -> None:
    assert fmt(value, spec) == text


def test_every_set_and_detector_has_its_detection_row(quick: BenchRun) -> None:
    report = quick.report
    text = format_report(report)
    for name, entry in report["sets"].items():
        for who in ("baseline", BEST, "tracking"):
            s = entry[who]
            assert row(text, name, who) == [
                name,
                who,
                fmt(s["median_ms"]),
                fmt(s["p99_ms"]),
                fmt(s["mean_ms"]),
                f"{s['recall']:.3f} ({s['found']}/{s['visible']})",
                str(s["false_positives"]),
                fmt(s["centre_error_px"], ".3f"),
                fmt(s["distance_error_pct"]),
            ]


def test_every_end_to_end_process_has_its_row_and_each_pass_its_ratio(quick: BenchRun) -> None:
    report = quick.report
    text = format_report(report)
    for name, entry in report["e2e"].items():
        label = f"{name} x{entry['passes']}"
        for who in (*E2E_DETECTORS, FLOOR):
            s = entry[who]
            cells = row(text, label, f"service {who}")
            assert cells[2:5] == [fmt(s["median_ms"]), fmt(s["mean_ms"]), fmt(s["p99_ms"])]
            assert cells[6:] == [
                fmt(s["overhead_median_ms"]),
                fmt(s["overhead_mean_ms"]),
                f"{s['recall']:.3f}",
                str(s["false_positives"]),
            ]
        bare = entry["baseline_detection"]
        assert row(text, label, "bare baseline")[2] == fmt(bare["median_ms"])
        (line,) = [ln for ln in text.splitlines() if per_pass(name).match(ln)]
        for who in E2E_DETECTORS:
            assert f"{who} " + ", ".join(f"{r:.2f}" for r in entry["pass_ratios"][who]) in line
    heading = next(ln for ln in text.splitlines() if ln.startswith("End to end"))
    assert f"camera put: {report['e2e_setup']['camera_put']}" in heading


def test_one_pass_has_no_per_pass_line(quick_no_shm: BenchRun) -> None:
    report = quick_no_shm.report
    text = format_report(report)
    for name in report["e2e"]:
        assert row(text, name, "service tracking")[0] == name  # no "x1"
        assert not [ln for ln in text.splitlines() if per_pass(name).match(ln)]


def test_every_throughput_run_has_its_row(quick: BenchRun) -> None:
    text = format_report(quick.report)
    for who, t in quick.report["throughput"].items():
        assert row(text, who, t["resolution"])[3:6] == [
            str(t["published"]),
            str(t["processed"]),
            str(t["dropped"]),
        ]


def test_the_paced_board_run_has_its_line(quick: BenchRun) -> None:
    paced = quick.report["boards"]["paced"]
    text = format_report(quick.report)
    line = next(ln for ln in text.splitlines() if "Hz into a service process" in ln)
    assert f"{paced['answered']} of {paced['frames']} frames answered" in line
    assert f"plain frames answered {paced['plain_answered']} of {paced['plain_frames']}" in line


def test_every_goal_has_its_row_and_verdict(quick: BenchRun) -> None:
    text = format_report(quick.report)
    for goal in quick.report["goals"]:
        cells = row(text, goal["goal"])
        assert cells[1:4] == [
            fmt(goal["value"], ".3f"),
            goal["threshold"],
            "PASS" if goal["pass"] else "FAIL",
        ]


def _side(report_row: dict[str, Any], key: str, names: tuple[str, ...] = PAIR) -> str:
    return "/".join(str(report_row[who][key]) for who in names)


def test_the_dataset_report_has_a_row_per_group_item_and_goal(corpus: Path) -> None:
    items = load_manifest(corpus / "manifest.json")
    report = evaluate(items, corpus / "data", Settings())
    text = format_dataset_report(report)
    for name, group in [*report["groups"].items(), ("all", report["all"])]:
        cells = joined(text, name)
        assert cells[1:3] == [str(group["opencv"]["frames"]), str(group["opencv"]["labelled"])]
        # OpenCV's figure / its best setting's / the service's, side by side
        assert cells[3] == _side(group, "found", SHOWN)
        assert cells[5] == _side(group, "false_ids", SHOWN)
        assert cells[6] == _side(group, "unverified", SHOWN)
        assert cells[7] == "/".join(fmt(group[who]["mean_ms"]) for who in SHOWN)
    for name, entry in report["dictionaries"].items():
        assert joined(text, name)[5] == _side(entry, "false_ids", SHOWN)
        assert joined(text, name)[7] == "/".join(fmt(entry[who]["mean_ms"]) for who in SHOWN)
    # the headers say which figure is which
    shown = r"found o/b/s +share o/b/s +false o/b/s +unverified o/b/s"
    assert len(re.findall(shown, text)) == 2
    assert "o/b/s = OpenCV default / OpenCV's best setting (windows 3-53 step 4, min" in text
    # the items stay OpenCV's default / the service's
    assert re.search(r"found o/s +share o/s +false o/s", text)
    for item in report["items"]:
        if item["negative"]:
            continue
        cells = joined(text, item["name"], item["kind"], item["dictionary"])
        assert cells[6] == _side(item, "found")
        assert cells[8] == _side(item, "false_ids")
        assert cells[9] == _side(item, "unverified")
    unknown = joined(text, "unknown", "image", "DICT_4X4_50")
    assert unknown[7] == "100.0%/100.0%"
    assert unknown[9] == "1/1"  # the unreadable marker's id: unverified, shown
    # a negative, read in both dictionaries of the manifest, in one row: its false ids summed
    negative = joined(text, "n-empty (negative)", "image", "2 dictionaries")
    false = [sum(i[w]["false_ids"] for i in report["items"] if i["negative"]) for w in PAIR]
    assert negative[8] == f"{false[0]}/{false[1]}" == "1/1"
    assert negative[-2:] == ["ids 1", "ids 1"]  # the unexpected id, OpenCV's and the service's
    lines = text.splitlines()
    for goal in report["goals"]:
        verdict = "PASS" if goal["pass"] else "FAIL"
        at = lines.index(f"{verdict}  {goal['goal']}: {goal['value']} ({goal['threshold']})")
        assert lines[at + 1].strip() == goal["labels"]
    assert max(len(line) for line in lines) <= 120  # every line fits 120 columns


def test_false_ids_by_size_stand_beside_each_other(corpus: Path) -> None:
    items = [i for i in load_manifest(corpus / "manifest.json") if i.name == "n-empty"]
    report = evaluate(items, corpus / "data", Settings())
    text = format_dataset_report(report)
    bucket = size_bucket(80.0)  # the unlabelled 80 px marker
    assert row(text, bucket)[3] == "1/1"
    assert report["all"]["service"]["false_buckets"][bucket] == 1
