"""End to end in lockstep through real ``zenoh-perception run`` processes and the transport
floor: every frame answered, recall and timing from the records, passes pooled."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from tests.bench.conftest import BenchRun
from zenoh_perception.settings import Settings
from zenoh_perception_bench import e2e
from zenoh_perception_bench.e2e import (
    LOCKSTEP_DEADLINE_MS,
    Lockstep,
    lockstep,
    record_detections,
)
from zenoh_perception_bench.framesets import Plan
from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR, ServiceError
from zenoh_perception_bench.scene import CameraModel, SceneGenerator
from zenoh_perception_bench.scoring import Tally

ENTRY_KEYS = {*E2E_DETECTORS, FLOOR, "baseline_detection", "camera", "passes", "pass_ratios"}


def test_the_sets_go_through_service_processes_in_passes(quick: BenchRun) -> None:
    report = quick.report
    e2e = report["e2e"]
    assert set(e2e) == {"HD720", "video", "real-camera video"}
    # every set goes through several passes (fresh services each), pooled
    assert {entry["passes"] for entry in e2e.values()} == {Plan.quick().e2e_passes}
    for name, entry in e2e.items():
        assert set(entry) == ENTRY_KEYS, name
        passes = entry["passes"]
        frames = report["sets"][name]["tracking"]["frames"] * passes
        # the transport floor answered every frame too
        assert entry[FLOOR]["records"] == entry[FLOOR]["frames"] == frames
        for who in E2E_DETECTORS:
            summary = entry[who]
            assert summary["frames"] == frames
            assert summary["records"] == frames  # every lockstep frame answered with a record
            assert 0.0 < summary["median_ms"] <= summary["p99_ms"]
            assert summary["visible"] == report["sets"][name]["tracking"]["visible"] * passes
            # what the records say was found (OpenCV's default service finds what it finds)
            if who == "opencv":
                assert summary["found"] == report["sets"][name]["baseline"]["found"] * passes
            assert summary["found"] > 0
            ratios = entry["pass_ratios"][who]
            assert len(ratios) == passes
            # (service - floor) / OpenCV: its sign is the machine's load, not the code's
            assert all(math.isfinite(r) for r in ratios)
            # the overhead: e2e minus the service's own detect_ms, frame by frame
            assert 0.0 < summary["detect_median_ms"] < summary["p99_ms"]
            assert summary["overhead_median_ms"] is not None
            assert summary["overhead_mean_ms"] == pytest.approx(
                summary["mean_ms"] - summary["detect_mean_ms"], abs=2e-3
            )
        assert entry[FLOOR]["found"] == 0  # the floor detects nothing: it only answers
        bare = entry["baseline_detection"]
        assert 0.0 < bare["median_ms"] <= bare["p99_ms"]
        camera = entry["camera"]
        assert camera["shm"] is (camera["unavailable"] is None)
        assert camera["shm_frames"] + camera["plain_frames"] > 2 * frames  # + warm-up frames


def test_plain_bytes_in_one_pass(quick_no_shm: BenchRun) -> None:
    report = quick_no_shm.report
    assert report["plan"]["e2e_passes"] == 1
    for entry in report["e2e"].values():
        assert entry["passes"] == 1
        assert entry["camera"]["shm"] is False
        for who in E2E_DETECTORS:
            assert entry[who]["records"] == entry[who]["frames"] > 0
            assert entry[who]["overhead_median_ms"] is not None
            assert len(entry["pass_ratios"][who]) == 1


def test_a_service_that_fails_to_start_is_reported_with_its_output() -> None:
    scene = SceneGenerator(CameraModel.named("VGA"), seed=3).random_scene(1, 0)
    with pytest.raises(ServiceError, match="detector must be one of"):
        lockstep(["bogus"], [scene], None, "bogus")


class _StartedError(Exception):
    """Raised in place of starting the services."""


def test_generated_frames_are_never_abandoned_for_a_busy_machine(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A frame abandoned at the deadline gets no answer, and the lockstep would wait for it
    # in vain: the services' deadline is far above what a busy machine makes of a frame.
    given: list[tuple[str, ...]] = []

    def services(*args: Any) -> None:
        _names, _endpoint, _session, _dictionary, flags = args
        given.append(tuple(flags))
        raise _StartedError

    monkeypatch.setattr(e2e, "services", services)
    scene = SceneGenerator(CameraModel.named("VGA"), seed=3).random_scene(1, 0)
    with pytest.raises(_StartedError):
        lockstep(["opencv"], [scene], None, "x")
    assert given == [("--frame-deadline-ms", str(LOCKSTEP_DEADLINE_MS))]
    assert 20 * Settings().limits.frame_deadline_ms <= LOCKSTEP_DEADLINE_MS


def test_a_record_s_tags_become_detections() -> None:
    corners = [[1.0, 2.0], [3.0, 2.0], [3.0, 4.0], [1.0, 4.0]]
    (detection,) = record_detections({"seq": 0, "tags": [{"tag_id": 7, "corners": corners}]})
    assert detection.tag_id == 7
    assert detection.corners.dtype == np.float32
    assert detection.corners.tolist() == corners
    assert record_detections(None) == []  # a frame without a record found nothing


def test_passes_pool_and_the_overhead_skips_frames_without_a_record() -> None:
    first = Lockstep(Tally(times_ms=[5.0, 6.0]), [{"detect_ms": 2.0}, None])
    first.extend(Lockstep(Tally(times_ms=[7.0]), [{"detect_ms": 3.0}]))
    assert first.latencies_ms == [5.0, 6.0, 7.0]
    assert first.overhead_ms() == [3.0, 4.0]
