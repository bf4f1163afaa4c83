"""Load: a camera flooding HD720 frames far faster than the service processes them.

The flood runs against an in-process service whose detector can be held inside one frame
(``HoldableDetector``), so "how many stale frames come before the marked one" is exact and
independent of thread timing; nothing here asserts a duration.
"""

from __future__ import annotations

import pytest

from tests.helpers import open_session
from tools.flood import HoldableDetector, LoadConfig, run_load
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings


def test_hd720_flood_keeps_memory_bounded_and_the_next_frame_is_answered_at_once(
    endpoint: str,
) -> None:
    settings = Settings.from_flat(stats_interval_s=0.0)
    gate = HoldableDetector(
        make_detector(settings.detection.detector, settings.detection.dictionary)
    )
    config = LoadConfig(resolution="HD720", ratio=8.0, count=240)
    with (
        open_session(listen=[endpoint]) as service_session,
        PerceptionService(service_session, settings, detector=gate),
        open_session(connect=[endpoint]) as camera,
    ):
        report = run_load(camera, gate, config)
    frames = report.status["frames"]
    # Every frame accounted for, and the service dropped (not queued) what it could not process.
    assert frames["received"] == config.warmup + max(10, config.count // 4) + config.count + 1
    assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]
    assert report.dropped_before_hold > 0  # while the worker ran freely, not only when held
    assert frames["rejected"] == 0
    # Memory: the flood carried 240 frames (~840 MiB); a queue would hold them, the mailbox
    # holds one. The bound is generous: 16 frames' worth of growth.
    assert report.rss_growth_kib < 16 * report.frame_bytes / 1024
    # No backlog: at the end of the flood, only the frame in progress and the newest wait...
    assert report.waiting_after_flood <= 2
    # ... and the marked frame is answered next, after at most the one in progress.
    assert report.stale_frames <= 1
    assert report.stale_records <= 1
    assert report.marked_tag_id == config.marked_tag
    assert report.marked_center == pytest.approx(report.expected_center, abs=1.0)
    assert report.problems() == []
