"""The PNG of detection latency against resolution."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from zenoh_perception_bench.plot import plot
from zenoh_perception_bench.runners import BEST


def _summary(median: float, p99: float) -> dict[str, float]:
    return {"median_ms": median, "p99_ms": p99}


def test_plot_draws_both_detectors_on_a_white_canvas(tmp_path: Path) -> None:
    report = {
        "sets": {
            name: {"baseline": _summary(k + 1.0, k + 2.0), "tracking": _summary(k + 0.5, k + 3.0)}
            for k, name in enumerate(("VGA", "HD720", "HD1080"))
        }
    }
    path = tmp_path / "sub" / "plot.png"
    plot(report, path)
    image = cv2.imread(str(path))
    assert image is not None
    assert image.shape == (600, 960, 3)
    # the two series' colours (BGR) are drawn
    for colour in ((40, 40, 220), (200, 110, 20)):
        assert np.all(image == colour, axis=2).any(), colour
    # a report made before OpenCV's best setting was run: no third series
    assert not np.all(image == (60, 160, 60), axis=2).any()


def test_plot_draws_opencv_s_best_setting_when_the_report_has_it(tmp_path: Path) -> None:
    report = {
        "sets": {
            name: {
                "baseline": _summary(k + 1.0, k + 2.0),
                BEST: _summary(k + 2.0, k + 4.0),
                "tracking": _summary(k + 0.5, k + 3.0),
            }
            for k, name in enumerate(("VGA", "HD720", "HD1080"))
        }
    }
    path = tmp_path / "plot.png"
    plot(report, path)
    image = cv2.imread(str(path))
    assert image is not None
    for colour in ((40, 40, 220), (60, 160, 60), (200, 110, 20)):
        assert np.all(image == colour, axis=2).any(), colour
