"""``zenoh-perception bench --quick``: runs end to end and reports what it should (no timings
are checked here: timings belong to the bench itself). The end-to-end part starts the real
``zenoh-perception run`` as subprocesses; the camera puts from shared memory by default, plain
bytes with ``--no-shm``."""

from __future__ import annotations

import io
import json
from typing import Any

import cv2
import numpy as np
import pytest

from zenoh_perception.bench.detectors import (
    E2E_DETECTORS,
    FLOOR,
    RESOLUTIONS,
    Plan,
    Progress,
    ServiceError,
    Tally,
    format_report,
    goals,
    lockstep,
    score,
)
from zenoh_perception.cli import main as cli
from zenoh_perception.detect.types import Detection
from zenoh_perception.scene import CameraModel, Effects, MarkerPose, SceneGenerator

SUMMARY_KEYS = {
    "frames",
    "median_ms",
    "p99_ms",
    "mean_ms",
    "recall",
    "found",
    "visible",
    "false_positives",
    "centre_error_px",
    "distance_error_pct",
}


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("bench")
    code = cli.main(
        ["bench", "--quick", "--json", str(out / "bench.json"), "--plot", str(out / "bench.png")]
    )
    data: dict[str, Any] = json.loads((out / "bench.json").read_text(encoding="utf-8"))
    assert code == (0 if all(g["pass"] for g in data["goals"]) else 1)
    data["_plot"] = str(out / "bench.png")
    return data


@pytest.fixture(scope="module")
def report_no_shm(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A smaller quick run whose camera puts plain bytes."""
    path = tmp_path_factory.mktemp("bench") / "bench.json"
    argv = ["bench", "--quick", "--no-shm", "--frames", "2", "--video-frames", "4", "--passes", "1"]
    code = cli.main([*argv, "--json", str(path)])
    data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    assert code == (0 if all(g["pass"] for g in data["goals"]) else 1)
    return data


def test_every_frame_set_has_both_detectors_with_sane_figures(report: dict[str, Any]) -> None:
    quick = Plan.quick()
    assert set(report["sets"]) == {
        *RESOLUTIONS,
        "video",
        "distractors",
        "real-camera",
        "real-camera video",
    }
    for name, entry in report["sets"].items():
        for who in ("baseline", "tracking"):
            summary = entry[who]
            assert set(summary) == SUMMARY_KEYS, (name, who)
            assert summary["frames"] > 0
            assert 0.0 < summary["median_ms"] <= summary["p99_ms"]
            assert 0.0 <= summary["recall"] <= 1.0
            assert summary["found"] <= summary["visible"]
        assert entry["tracking"]["visible"] == entry["baseline"]["visible"]  # the same frames
        counters = entry["tracking_counters"]
        assert counters["frames"] == entry["tracking"]["frames"]
        assert 1 <= counters["scans"] <= counters["frames"]
        if not entry["video"]:  # independent frames: every one is scanned
            assert counters["scans"] == counters["frames"]
    # on the video, whole frames are read only now and then
    video = report["sets"]["video"]["tracking_counters"]
    assert video["scans"] < video["frames"]
    assert report["sets"]["video"]["tracking"]["frames"] == quick.video_frames
    assert report["sets"]["VGA"]["tracking"]["frames"] == quick.frames
    # look-alikes fool OpenCV's detector, and so the service's, which it decides for
    assert report["sets"]["distractors"]["baseline"]["false_positives"] > 0


def test_end_to_end_and_throughput_ran_through_service_processes(report: dict[str, Any]) -> None:
    e2e = report["e2e"]
    assert set(e2e) == {"HD720", "video", "real-camera video"}
    # both sets go through several passes (fresh services each), pooled
    assert {entry["passes"] for entry in e2e.values()} == {Plan.quick().e2e_passes}
    assert Plan.quick().e2e_passes > 1
    for name, entry in e2e.items():
        assert set(entry) == {
            *E2E_DETECTORS,
            FLOOR,
            "baseline_detection",
            "camera",
            "passes",
            "pass_ratios",
        }  # no "none" row
        passes = entry["passes"]
        # the transport floor answered every frame too, faster than any service
        assert entry[FLOOR]["records"] == entry[FLOOR]["frames"]
        for who in E2E_DETECTORS:
            summary = entry[who]
            assert summary["mean_ms"] > entry[FLOOR]["mean_ms"]
            frames = report["sets"][name]["tracking"]["frames"] * passes
            assert summary["frames"] == frames
            assert summary["records"] == frames  # every lockstep frame answered with a record
            assert 0.0 < summary["median_ms"] <= summary["p99_ms"]
            assert summary["visible"] == report["sets"][name]["tracking"]["visible"] * passes
            ratios = entry["pass_ratios"][who]
            assert len(ratios) == passes
            assert all(r > 0.0 for r in ratios)
            # the overhead column: e2e minus the service's own detect_ms, frame by frame
            assert 0.0 < summary["detect_median_ms"] < summary["p99_ms"]
            assert summary["overhead_median_ms"] is not None
            assert summary["overhead_mean_ms"] == pytest.approx(
                summary["mean_ms"] - summary["detect_mean_ms"], abs=2e-3
            )
        camera = entry["camera"]
        assert camera["shm"] is (camera["unavailable"] is None)
        assert camera["shm_frames"] + camera["plain_frames"] > 2 * frames  # + warm-up frames
    setup = report["e2e_setup"]
    assert setup["shm_requested"] is True
    assert setup["shm"] is (setup["shm_fallback"] is None)  # SHM unless this machine lacks it
    for who in E2E_DETECTORS:
        run = report["throughput"][who]
        assert run["published"] == round(60 * Plan.quick().throughput_s)
        assert run["received"] == run["published"]  # the bench publishes with congestion block
        assert run["processed"] + run["dropped"] == run["received"]
        assert run["resolution"] == "1920x1080"
        assert run["latency_p50_ms"] is not None
        assert run["camera"]["shm"] is setup["shm"]
    text = format_report(report)
    assert "overhead med" in text
    for name in e2e:
        assert f"{name} x{e2e[name]['passes']}" in text
        each = ", ".join(f"{r:.2f}" for r in e2e[name]["pass_ratios"]["tracking"])
        assert f"tracking {each}" in text
    assert "no detector" not in text
    assert setup["camera_put"] in text


def test_no_shm_puts_plain_bytes_and_says_so(report_no_shm: dict[str, Any]) -> None:
    setup = report_no_shm["e2e_setup"]
    assert (setup["shm_requested"], setup["shm"]) == (False, False)
    assert setup["camera_put"].startswith("plain bytes")
    cameras = [e["camera"] for e in report_no_shm["e2e"].values()]
    cameras += [t["camera"] for t in report_no_shm["throughput"].values()]
    assert all(c["shm"] is False for c in cameras)
    for entry in report_no_shm["e2e"].values():
        for who in E2E_DETECTORS:
            assert entry[who]["records"] == entry[who]["frames"] > 0
            assert entry[who]["overhead_median_ms"] is not None
    assert "camera put: plain bytes" in format_report(report_no_shm)
    # one pass: no per-pass figures to pool or list
    assert report_no_shm["plan"]["e2e_passes"] == 1
    notes = [g["note"] for g in report_no_shm["goals"] if "e2e - floor" in g["goal"]]
    assert len(notes) == 3  # the two videos' and the independent frames'
    assert all(n.endswith("; one pass") for n in notes)
    assert "per pass" not in format_report(report_no_shm)


def test_a_service_that_fails_to_start_is_reported_with_its_output() -> None:
    scene = SceneGenerator(CameraModel.named("VGA"), seed=3).random_scene(1, 0)
    with pytest.raises(ServiceError, match="detector must be one of"):
        lockstep(["bogus"], [scene], None, "bogus")


def test_goals_have_a_verdict_and_the_plot_is_written(report: dict[str, Any]) -> None:
    names = [g["goal"] for g in report["goals"]]
    assert any(name.startswith("video: service mean e2e - floor") for name in names)
    assert any(name.startswith("HD720: service median e2e - floor") for name in names)
    assert any(name.startswith("HD1080 at 60 Hz") for name in names)
    assert all(isinstance(g["pass"], bool) and g["threshold"] for g in report["goals"])
    assert goals({k: v for k, v in report.items() if k != "goals"}) == report["goals"]
    image = cv2.imread(report["_plot"])
    assert image is not None
    assert image.shape == (600, 960, 3)
    assert int(image.min()) < 100  # something was drawn on the white canvas
    text = format_report(report)
    for heading in ("Detection", "End to end", "Throughput", "Goals"):
        assert heading in text
    assert text.count("PASS") + text.count("FAIL") == len(report["goals"])


def test_score_counts_hits_misses_and_false_positives() -> None:
    camera = CameraModel.named("VGA")
    scene = SceneGenerator(camera, seed=1, effects=Effects.clean()).scene_from_poses(
        [MarkerPose(3, 0.2, (-0.3, 0.0, 1.5)), MarkerPose(9, 0.2, (0.3, 0.0, 1.5))]
    )
    first = scene.markers[0]
    exact = Detection(first.tag_id, first.corners.astype(np.float32))
    wrong_place = Detection(9, first.corners.astype(np.float32))  # id 9, but where 3 is
    found, visible, false_pos, centre, distance = score(scene, [exact, wrong_place])
    assert (found, visible, false_pos) == (1, 2, 1)
    assert centre == [pytest.approx(0.0, abs=1e-4)]
    assert distance[0] == pytest.approx(0.0, abs=1e-3)
    tally = Tally()
    tally.add(scene, [exact], 2.0)
    tally.add(scene, [], 4.0)
    summary = tally.summary()
    assert summary["recall"] == pytest.approx(0.25)
    assert summary["median_ms"] == pytest.approx(3.0)


def test_progress_bar_ends_full_on_one_line() -> None:
    stream = io.StringIO()
    bar = Progress(3, stream=stream, width=10)
    for _ in range(5):
        bar.step("work")
    bar.close()
    text = stream.getvalue()
    assert text.endswith("\n")
    assert "[##########]    3/3 work" in text
