"""The generated look-alike sets of the bench and their goals."""

from __future__ import annotations

from typing import Any

from zenoh_perception_bench.goals import lookalike_goals
from zenoh_perception_bench.lookalikes import lookalike_report

#: Two families (every family is tested in tests/detect/test_verify.py).
FEW = ("DICT_4X4_50", "DICT_APRILTAG_36h11")


def test_the_service_reports_no_look_alike_and_every_true_tag_opencv_finds() -> None:
    report = lookalike_report(1, 2024, families=FEW)
    assert set(report) == set(FEW)
    assert sum(row["opencv"]["lookalike_ids"] for row in report.values()) > 0
    assert all(g["pass"] for g in lookalike_goals(report)), lookalike_goals(report)


def test_without_the_veto_the_goals_fail() -> None:
    report = lookalike_report(1, 2024, verify=False, families=FEW)
    failed = [g["goal"] for g in lookalike_goals(report) if not g["pass"]]
    assert any("false ids" in name for name in failed)


def _row(service_false: int, service_found: int, opencv_found: int) -> dict[str, Any]:
    return {
        "opencv": {"false_ids": 9, "true_found": opencv_found, "lookalike_ids": 9},
        "service": {"false_ids": service_false, "true_found": service_found, "lookalike_ids": 0},
    }


def test_goals_ask_for_no_false_id_and_every_true_tag() -> None:
    assert all(g["pass"] for g in lookalike_goals({"F": _row(0, 5, 5)}))
    false_id, lost = lookalike_goals({"F": _row(1, 4, 5)})
    assert not false_id["pass"] and not lost["pass"]
