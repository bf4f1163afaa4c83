"""A detector by name, as the settings give it."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.tracking import TrackingDetector
from zenoh_perception.detect.types import DETECTORS
from zenoh_perception.errors import SettingsError
from zenoh_perception_bench.scene import render_markers


def test_make_detector_names() -> None:
    assert isinstance(make_detector("opencv", "DICT_5X5_100"), OpenCvDetector)
    assert isinstance(make_detector("tracking", "DICT_APRILTAG_36h11"), TrackingDetector)
    with pytest.raises(SettingsError, match="unknown detector"):
        make_detector("fast", "DICT_4X4_50")
    with pytest.raises(SettingsError, match="unknown ArUco dictionary"):
        make_detector("opencv", "DICT_9X9_1")


@pytest.mark.parametrize("name", DETECTORS)
def test_every_detector_name_makes_a_detector_that_finds_a_tag(name: str) -> None:
    corners = np.array([[100, 100], [260, 100], [260, 260], [100, 260]], dtype=np.float64)
    frame = np.ascontiguousarray(render_markers(640, 480, [(9, corners)])[:, :, 1])
    assert [d.tag_id for d in make_detector(name, "DICT_4X4_50").detect(frame)] == [9]


def test_the_tracking_period_comes_from_the_settings() -> None:
    detector = make_detector("tracking", "DICT_4X4_50", full_scan_period=7)
    assert isinstance(detector, TrackingDetector)
    assert detector.config.full_scan_period == 7
    with pytest.raises(SettingsError):
        make_detector("tracking", "DICT_4X4_50", full_scan_period=0)
