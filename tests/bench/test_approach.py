"""The approach set: a tag growing from 30 to 400 px, beside a second tag and look-alikes."""

from __future__ import annotations

import math

import numpy as np

from zenoh_perception_bench.approach import SIDE_PX, approach_frames, summary


def test_the_tag_grows_log_evenly_over_the_approach() -> None:
    frames = approach_frames("VGA", 5, seed=4)
    sides = [f.side_px for f in frames]
    assert math.isclose(sides[0], SIDE_PX[0]) and math.isclose(sides[-1], SIDE_PX[1])
    ratios = np.diff(np.log(sides))
    assert np.allclose(ratios, ratios[0])
    assert frames[0].image.shape == (480, 640, 4)
    again = approach_frames("VGA", 5, seed=4)
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, again, strict=True))


def test_the_summary_pairs_each_frame_with_the_peer_s_and_leaves_out_unanswered_ones() -> None:
    run = {
        "sides_px": [30.0, 40.0, 100.0, 200.0],
        "tag_ms": {
            "opencv-peer": [4.0, 4.0, 4.0, 6.0],
            "coarse": [4.2, 4.4, 2.0, 2.0],
            "whole": [4.5, 4.5, 5.0, math.nan],
        },
        "record_ms": {"opencv-peer": [4.0] * 4, "coarse": [5.0] * 4, "whole": [5.0] * 4},
    }
    far, near = summary(run)
    assert far["frames"] == 2 and math.isclose(far["coarse_minus_peer_ms"], 0.3)
    assert near["frames"] == 1  # the frame the whole path did not answer is left out
    assert near["coarse_over_peer"] == 0.5 and near["met"]
