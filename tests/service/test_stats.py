"""Service counters, latency percentiles, frame rate and budget, and the log gate (fake clock)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.service.stats import LogGate, ServiceStats


def test_stats_percentiles_and_counts() -> None:
    now = [100.0]
    stats = ServiceStats(clock=lambda: now[0])
    for i in range(100):
        stats.on_received(dropped_one=i % 10 == 0)
        now[0] += 0.1
        stats.on_processed(float(i + 1))
    stats.on_rejected("bad_cdr")
    stats.on_rejected("bad_cdr")
    now[0] += 0.05  # off the 0.1 s grid: no frame sits on the edge of the 5 s fps window
    snap = stats.snapshot()
    assert (snap.received, snap.processed, snap.dropped) == (100, 100, 10)
    assert snap.rejected == {"bad_cdr": 2}
    assert snap.latency_p50_ms == pytest.approx(50.5)
    assert snap.latency_p99_ms == pytest.approx(99.01)
    assert snap.fps == pytest.approx(10.0)
    assert snap.as_dict()["frames"]["rejected"] == 2


def test_fps_is_frames_over_wall_time() -> None:
    """Two frames done 1 ms apart, then a quiet second: 2 frames in 2 s of uptime, not 1000
    frames per second."""
    now = [0.0]
    stats = ServiceStats(clock=lambda: now[0])
    now[0] = 1.0
    stats.on_processed(1.0)
    now[0] = 1.001
    stats.on_processed(1.0)
    now[0] = 2.0
    assert stats.snapshot().fps == pytest.approx(1.0)
    now[0] = 10.0  # the window (5 s) is full and holds both frames no more
    assert stats.snapshot().fps == 0.0
    for _ in range(50):  # 10 Hz for 5 s
        now[0] += 0.1
        stats.on_processed(1.0)
    now[0] += 0.05
    assert stats.snapshot().fps == pytest.approx(10.0)


def test_budget_counts_frames_over_it_and_keeps_the_worst_times() -> None:
    stats = ServiceStats(frame_budget_ms=10.0)
    stats.on_processed(5.0, frame_ms=9.0, detect_ms=7.0)
    stats.on_processed(25.0, frame_ms=24.5, detect_ms=20.0)
    stats.on_processed(12.0, frame_ms=11.0, detect_ms=21.0)
    budget = stats.snapshot().as_dict()["budget"]
    assert budget == {
        "frame_budget_ms": 10.0,
        "over_budget": 2,
        "frame_ms_max": 24.5,
        "detect_ms_max": 21.0,
        "frame_deadline_ms": None,
        "abandoned": 0,
        "abandoned_ms_max": 0.0,
        "abandoned_ms_last": 0.0,
    }


def test_abandoned_frames_are_counted_with_their_longest_and_last_time() -> None:
    stats = ServiceStats(frame_deadline_ms=400.0)
    stats.on_abandoned(431.5)
    stats.on_abandoned(402.0)
    budget = stats.snapshot().as_dict()["budget"]
    assert budget["frame_deadline_ms"] == 400.0
    assert budget["abandoned"] == 2
    assert budget["abandoned_ms_max"] == 431.5
    assert budget["abandoned_ms_last"] == 402.0


def test_publish_processing_and_camera_info_counters() -> None:
    stats = ServiceStats()
    stats.on_publish_error("record")
    stats.on_processing_error("debug_image")
    stats.on_camera_info("bad_intrinsics")
    stats.on_camera_info(None)
    status = stats.snapshot().as_dict()
    assert status["publish_errors"] == {
        "tag": 0,
        "record": 1,
        "debug_image": 0,
        "detections": 0,
        "tf": 0,
    }
    assert status["processing_errors"] == {"debug_image": 1}
    assert status["camera_info"] == {
        "received": 2,
        "rejected_by_reason": {"bad_intrinsics": 1},
        "size_mismatch_frames": 0,
    }
    # Neither is a frame: the frame counters stay as they were.
    assert status["frames"] == {"received": 0, "processed": 0, "dropped": 0, "rejected": 0}


def test_log_gate_admits_once_per_interval_and_reports_suppressed() -> None:
    now = [0.0]
    gate = LogGate(5.0, clock=lambda: now[0])
    assert gate.admit("bad_cdr") == 0
    assert gate.admit("bad_cdr") is None
    assert gate.admit("bad_cdr") is None
    assert gate.admit("size_mismatch") == 0
    now[0] = 5.0
    assert gate.admit("bad_cdr") == 2


@given(
    latencies=st.lists(st.floats(min_value=0.0, max_value=1e4), min_size=1, max_size=60),
    window=st.integers(min_value=1, max_value=30),
)
def test_percentiles_are_those_of_the_last_window_of_frames(
    latencies: list[float], window: int
) -> None:
    stats = ServiceStats(window=window, clock=lambda: 0.0)
    for latency in latencies:
        stats.on_processed(latency)
    snap = stats.snapshot()
    kept = np.asarray(latencies[-window:])
    assert snap.processed == len(latencies)
    assert snap.latency_p50_ms == pytest.approx(float(np.percentile(kept, 50)))
    assert snap.latency_p99_ms == pytest.approx(float(np.percentile(kept, 99)))
    assert snap.latency_mean_ms == pytest.approx(float(kept.mean()))
    assert snap.latency_p50_ms <= snap.latency_p99_ms


@given(
    st.lists(
        st.one_of(
            st.booleans().map(lambda dropped: ("received", dropped)),
            st.sampled_from(["bad_cdr", "size_mismatch", "bad_stamp"]).map(
                lambda reason: ("rejected", reason)
            ),
        ),
        max_size=50,
    )
)
def test_frame_counters_add_up(events: list[tuple[str, object]]) -> None:
    stats = ServiceStats()
    for kind, value in events:
        if kind == "received":
            stats.on_received(dropped_one=bool(value))
        else:
            stats.on_rejected(str(value))
    frames = stats.snapshot().as_dict()["frames"]
    received = [value for kind, value in events if kind == "received"]
    rejected = [value for kind, value in events if kind == "rejected"]
    assert frames == {
        "received": len(received),
        "processed": 0,
        "dropped": sum(bool(v) for v in received),
        "rejected": len(rejected),
    }
    assert stats.snapshot().rejected == dict(Counter(str(v) for v in rejected))


def test_a_fresh_service_reports_zeros() -> None:
    status = ServiceStats(clock=lambda: 5.0).snapshot().as_dict()
    assert status["frames"] == {"received": 0, "processed": 0, "dropped": 0, "rejected": 0}
    assert status["latency_ms"] == {"p50": 0.0, "p99": 0.0, "mean": 0.0}
    assert (status["fps"], status["uptime_s"]) == (0.0, 0.0)
    assert status["budget"]["frame_budget_ms"] is None


def test_log_gate_forgets_its_oldest_key_past_max_keys() -> None:
    gate = LogGate(5.0, clock=lambda: 0.0, max_keys=3)
    for key in ("a", "b", "c", "d"):
        assert gate.admit(key) == 0
    assert len(gate._last) == 3  # the bound is the point
    assert gate.admit("a") == 0  # forgotten: let through again
    assert gate.admit("d") is None  # remembered: still limited
