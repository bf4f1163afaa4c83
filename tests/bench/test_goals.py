"""The goals: each with a value, a threshold and a verdict that follows from the figures."""

from __future__ import annotations

from typing import Any

import pytest

from tests.bench.conftest import BenchRun
from zenoh_perception_bench.goals import (
    CENTRE_ERROR_PX,
    dataset_goals,
    goals,
    lost_tags,
    own_cost_ms,
)


def _verdicts(rows: list[dict[str, Any]]) -> dict[str, bool]:
    return {row["goal"]: row["pass"] for row in rows}


def test_the_quick_run_has_every_goal_with_a_verdict(quick: BenchRun) -> None:
    report = quick.report
    names = [g["goal"] for g in report["goals"]]
    assert any(name.startswith("video: service mean e2e - floor") for name in names)
    assert any(name.startswith("real-camera video: service mean e2e - floor") for name in names)
    assert any(name.startswith("HD720: service median e2e - floor") for name in names)
    assert "HD1080 at 60 Hz: every frame processed" in names
    for name in report["sets"]:
        assert f"{name}: tags found >= OpenCV default" in names
    for family in report["lookalikes"]:
        assert f"look-alikes {family}: false ids" in names
    assert all(isinstance(g["pass"], bool) and g["threshold"] for g in report["goals"])
    # the goals are a function of the rest of the report
    assert goals({k: v for k, v in report.items() if k != "goals"}) == report["goals"]


def test_the_own_cost_goal_notes_each_pass(quick: BenchRun, quick_no_shm: BenchRun) -> None:
    for run in (quick, quick_no_shm):
        e2e = run.report["e2e"]
        rows = [g for g in run.report["goals"] if "e2e - floor" in g["goal"]]
        assert len(rows) == 3  # the two videos' and the independent frames'
        for row in rows:
            entry = e2e[row["goal"].split(":")[0]]
            if entry["passes"] == 1:
                assert row["note"].endswith("; one pass")
            else:
                each = ", ".join(f"{r:.2f}" for r in entry["pass_ratios"]["tracking"])
                assert row["note"].endswith(f"own-cost ratio of each: {each}")


def _set(found: int, false_ids: int, centre: float | None) -> dict[str, Any]:
    return {"found": found, "false_positives": false_ids, "centre_error_px": centre}


def test_a_set_where_the_service_does_worse_fails() -> None:
    report = {
        "sets": {
            "good": {"baseline": _set(5, 1, 0.2), "tracking": _set(5, 1, 0.1)},
            "bad": {"baseline": _set(5, 0, 0.2), "tracking": _set(4, 1, CENTRE_ERROR_PX + 0.1)},
        }
    }
    rows = goals(report)
    assert _verdicts(rows) == {
        "good: tags found >= OpenCV default": True,
        "good: false ids <= OpenCV default": True,
        "bad: tags found >= OpenCV default": False,
        "bad: false ids <= OpenCV default": False,
        "median centre error, worst set (px)": False,
    }
    assert rows[2]["value"] == 4.0
    assert rows[2]["threshold"] == ">= 5"
    assert rows[-1]["value"] == pytest.approx(CENTRE_ERROR_PX + 0.1)


def test_own_cost_is_end_to_end_minus_the_floor() -> None:
    entry = {"tracking": {"mean_ms": 9.5}, "floor": {"mean_ms": 1.5}}
    assert own_cost_ms(entry, "tracking", "mean_ms") == 8.0


def _item(name: str, opencv: dict[str, int], service: dict[str, int]) -> dict[str, Any]:
    def summary(found: dict[str, int]) -> dict[str, Any]:
        return {
            "found": sum(found.values()),
            "found_ids": found,
            "labelled": 4,
            "share_found": sum(found.values()) / 4,
            "false_ids": 0,
            "unverified": 0,
            "frames": 1,
        }

    return {
        "name": name,
        "kind": "image",
        "dictionary": "DICT_4X4_50",
        "negative": False,
        "unsure": False,
        "opencv": summary(opencv),
        "service": summary(service),
    }


def test_a_tag_lost_against_opencv_fails_id_by_id() -> None:
    # the same count found, but id 7 that OpenCV finds is lost: a failure
    swapped = _item("desk", {"3": 1, "7": 1}, {"3": 1, "9": 1})
    assert lost_tags(swapped) == {"7": 1}
    assert lost_tags(_item("ok", {"3": 1}, {"3": 1, "7": 1})) == {}
    report = {"groups": {}, "items": [swapped], "settings": {"detector": "tracking"}}
    (lost, labels, sure) = dataset_goals(report)
    assert (lost["value"], lost["pass"]) == (1, False)
    # half the labelled markers found: the labels are believed (a share of 0.5 passes)
    assert (labels["value"], labels["pass"]) == (0.5, True)
    assert lost["note"] == "lost on desk id 7"
    assert lost["labels"] == "service 2/4 (50.0 %), OpenCV 2/4 (50.0 %)"
    assert sure["goal"] == "sure positives: unlabelled ids (service)" and sure["pass"]
