"""``zenoh-perception bench``: the generated bench's report, plan and exit code (no timings are
checked here: timings belong to the bench itself)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import cv2
import pytest

from tests.bench.conftest import QUICK_PLAN, BenchRun
from zenoh_perception_bench import generated
from zenoh_perception_bench.framesets import BOARD_SQUARES_QUICK, RESOLUTIONS, Plan
from zenoh_perception_bench.reach import DISTANCES_M
from zenoh_perception_bench.runners import BEST
from zenoh_perception_bench.scene.boards import BOARD_KINDS
from zenoh_perception_bench.scoring import Tally

SUMMARY_KEYS = set(Tally().summary())
REPORT_KEYS = {
    "version",
    "machine",
    "plan",
    "sets",
    "lookalikes",
    "range",
    "e2e",
    "throughput",
    "e2e_setup",
    "boards",
    "goals",
}
SET_KEYS = {"resolution", "video", "baseline", BEST, "tracking", "tracking_counters"}


def test_the_exit_code_follows_the_goals(quick: BenchRun, quick_no_shm: BenchRun) -> None:
    for run in (quick, quick_no_shm):
        assert run.code == (0 if all(g["pass"] for g in run.report["goals"]) else 1)


def test_the_report_has_every_part_and_the_plan(quick: BenchRun) -> None:
    report = quick.report
    assert set(report) == REPORT_KEYS
    plan = QUICK_PLAN
    assert report["plan"] == {
        "frames_per_resolution": plan.frames,
        "video_frames": plan.video_frames,
        "video_fps": plan.video_fps,
        "distractor_frames": plan.distractor_frames,
        "lookalike_frames": plan.lookalike_frames,
        "throughput_s": plan.throughput_s,
        "seed": plan.seed,
        "e2e_passes": plan.e2e_passes,
        "busy_board_frames": plan.busy_board_frames,
        "range_frames": plan.range_frames,
    }
    assert report["machine"]["cpus"] >= 1


def test_every_frame_set_has_both_detectors_with_sane_figures(quick: BenchRun) -> None:
    report = quick.report
    quick_plan = QUICK_PLAN
    assert set(report["sets"]) == {
        *RESOLUTIONS,
        "video",
        "distractors",
        "real-camera",
        "real-camera video",
    }
    for name, entry in report["sets"].items():
        assert set(entry) == SET_KEYS, name
        for who in ("baseline", BEST, "tracking"):
            summary = entry[who]
            assert set(summary) == SUMMARY_KEYS, (name, who)
            assert summary["frames"] > 0
            assert 0.0 < summary["median_ms"] <= summary["p99_ms"]
            assert 0.0 <= summary["recall"] <= 1.0
            assert summary["found"] <= summary["visible"]
        # the same frames
        assert entry["tracking"]["visible"] == entry["baseline"]["visible"]
        assert entry[BEST]["visible"] == entry["baseline"]["visible"]
        assert entry[BEST]["frames"] == entry["baseline"]["frames"]
        counters = entry["tracking_counters"]
        assert counters["frames"] == entry["tracking"]["frames"]
        assert 1 <= counters["scans"] <= counters["frames"]
        if not entry["video"]:  # independent frames: every one is scanned
            assert counters["scans"] == counters["frames"]
    # on the video, whole frames are read only now and then
    video = report["sets"]["video"]["tracking_counters"]
    assert video["scans"] < video["frames"]
    assert report["sets"]["video"]["tracking"]["frames"] == quick_plan.video_frames
    assert report["sets"]["VGA"]["tracking"]["frames"] == quick_plan.frames
    # look-alikes fool OpenCV's detector, and so the service's, which it decides for
    assert report["sets"]["distractors"]["baseline"]["false_positives"] > 0


def test_the_range_figure_has_each_detector(quick: BenchRun) -> None:
    case = quick.report["range"]
    names = ["opencv", BEST, "service"]
    assert list(case["found_share"]) == list(case["range_m"]) == names
    for name in names:
        shares = case["found_share"][name]
        assert list(shares) == [str(d) for d in DISTANCES_M]
        assert all(0.0 <= share <= 1.0 for share in shares.values())
        assert case["range_m"][name] in (0.0, *DISTANCES_M)
    # a 20 cm tag at 2 m is about 90 px wide at HD720: every detector finds it
    assert all(case["found_share"][name]["2.0"] == 1.0 for name in names)
    assert case["frames_per_distance"] == QUICK_PLAN.range_frames


def test_the_setup_says_how_the_camera_put_its_frames(
    quick: BenchRun, quick_no_shm: BenchRun
) -> None:
    setup = quick.report["e2e_setup"]
    assert setup["shm_requested"] is True
    assert setup["shm"] is (setup["shm_fallback"] is None)  # SHM unless this machine lacks it
    expected = "shared memory" if setup["shm"] else "plain bytes"
    assert setup["camera_put"].startswith(expected)
    plain = quick_no_shm.report["e2e_setup"]
    assert (plain["shm_requested"], plain["shm"]) == (False, False)
    assert plain["camera_put"].startswith("plain bytes")
    assert plain["shm_plain_frames"] is None


def test_the_plot_is_written(quick: BenchRun) -> None:
    image = cv2.imread(str(quick.plot))
    assert image is not None
    assert image.shape == (600, 960, 3)


def _args(tmp_path: Path, **overrides: Any) -> argparse.Namespace:
    values: dict[str, Any] = {
        "quick": True,
        "frames": None,
        "video_frames": None,
        "seed": None,
        "passes": None,
        "no_e2e": True,
        "no_shm": False,
        "json": tmp_path / "out" / "bench.json",
        "plot": None,
    }
    return argparse.Namespace(**{**values, **overrides})


@pytest.mark.parametrize("passed", [True, False])
def test_main_writes_the_report_and_exits_1_when_a_goal_fails(
    passed: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: list[tuple[Plan, bool, bool]] = []
    report = {"sets": {}, "goals": [{"goal": "g", "value": 1.0, "threshold": "t", "pass": passed}]}

    def run_bench(plan: Plan, *, with_e2e: bool, shm: bool) -> dict[str, Any]:
        seen.append((plan, with_e2e, shm))
        return report

    monkeypatch.setattr(generated, "run_bench", run_bench)
    monkeypatch.setattr(generated, "format_report", lambda r: "")
    args = _args(tmp_path, frames=0, video_frames=1, seed=7, passes=0, no_shm=True)
    assert generated.main(args) == (0 if passed else 1)
    written = json.loads(args.json.read_text(encoding="utf-8"))
    assert written == report
    # the flags change the quick plan, within bounds
    ((plan, with_e2e, shm),) = seen
    assert plan == Plan(
        frames=1,
        video_frames=2,
        distractor_frames=6,
        lookalike_frames=1,
        throughput_s=1.0,
        seed=7,
        e2e_passes=1,
        board_squares=BOARD_SQUARES_QUICK,
        busy_board_frames=10,
        range_frames=4,
    )
    assert (with_e2e, shm) == (False, False)


def test_the_full_plan_is_the_documented_one() -> None:
    assert Plan.full() == Plan(
        frames=60,
        video_frames=300,
        video_fps=60.0,
        distractor_frames=40,
        lookalike_frames=4,
        throughput_s=8.0,
        seed=2024,
        e2e_passes=3,
    )
    quick = Plan.quick()
    assert (quick.frames, quick.video_frames, quick.e2e_passes) == (6, 24, 2)
    assert quick.e2e_passes > 1  # the quick run pools passes too


def test_the_board_case_has_every_board_and_both_detectors(quick: BenchRun) -> None:
    boards = quick.report["boards"]
    kinds = {(row["kind"], row["square_px"]) for row in boards["frames"]}
    assert kinds == {(k, s) for k in BOARD_KINDS for s in QUICK_PLAN.board_squares}
    for name in ("opencv", "service"):
        summary = boards["summary"][name]
        assert summary["tags"] == 2 * len(kinds)
        assert summary["median_ms"] > 0 and boards["after_storm_ms"][name] > 0
    # the service finds every tag OpenCV's default finds beside the boards
    assert boards["summary"]["service"]["found"] >= boards["summary"]["opencv"]["found"]
    assert boards["plain_frame_cost_ms"] > 0
    goals = {g["goal"] for g in quick.report["goals"]}
    assert "boards: service median ms a frame" in goals


def test_a_board_past_the_frame_deadline_is_answered_with_its_tags(
    quick: BenchRun, quick_no_shm: BenchRun
) -> None:
    # the first frame is abandoned at the deadline; the detectors built after it keep the
    # board away from their first read, so the frames after it are answered (before, every
    # replacement read the board whole again and was abandoned in turn)
    for run in (quick, quick_no_shm):
        busy = run.report["boards"]["busy"]
        frames = busy["status_frames"]
        assert busy["frames"] == run.report["plan"]["busy_board_frames"]
        assert frames["received"] == busy["frames"]
        assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]
        assert busy["answered_with_tags"] >= busy["board_frames"] // 2, busy


def test_the_boards_go_to_a_service_process_at_30_hz(
    quick: BenchRun, quick_no_shm: BenchRun
) -> None:
    for run in (quick, quick_no_shm):
        paced = run.report["boards"]["paced"]
        assert paced["rate_hz"] == 30.0
        assert paced["frames"] == generated.PACED_FRAMES
        # every frame sent reached the service and is accounted for there
        frames = paced["status_frames"]
        assert frames["received"] == paced["frames"]
        assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]
        assert paced["answered"] == frames["processed"] > 0
        assert 0 <= paced["plain_answered"] <= paced["plain_frames"] == paced["frames"] // 4
