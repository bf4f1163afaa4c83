"""HD1080 at 60 Hz to each service process: every frame put is received and accounted for."""

from __future__ import annotations

from tests.bench.conftest import BenchRun
from zenoh_perception_bench.framesets import Plan
from zenoh_perception_bench.processes import E2E_DETECTORS
from zenoh_perception_bench.throughput import THROUGHPUT_HZ


def test_every_service_got_every_frame_at_60_hz(quick: BenchRun, quick_no_shm: BenchRun) -> None:
    assert set(quick.report["throughput"]) == set(E2E_DETECTORS)
    for run in (quick, quick_no_shm):
        shm = run.report["e2e_setup"]["shm"]
        for who in E2E_DETECTORS:
            result = run.report["throughput"][who]
            assert result["rate_hz"] == THROUGHPUT_HZ
            assert result["published"] == round(THROUGHPUT_HZ * Plan.quick().throughput_s)
            # the bench publishes with congestion control "block": none lost on the way
            assert result["received"] == result["published"]
            # every frame received is answered, replaced by a newer one, or (on a loaded
            # machine, past the frame deadline) abandoned and counted
            assert (
                result["processed"] + result["dropped"] + result["rejected"] == result["received"]
            )
            assert result["processed"] > 0
            assert result["resolution"] == "1920x1080"
            assert 0.0 < result["latency_p50_ms"] <= result["latency_p99_ms"]
            assert result["camera"]["shm"] is shm
