"""``bench --poses``: rendered frames with exact poses, the methods' errors and the goals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from zenoh_perception_bench import poses


def test_a_rendered_tag_s_true_pose_has_no_error_and_its_corners_are_in_the_frame() -> None:
    rng = np.random.default_rng(0)
    rotation, tvec = poses.random_view("VGA", 3.0, rng)
    image, truth = poses.render("VGA", rotation, tvec, 0.7, rng)
    assert image.shape == (480, 640, 4)
    assert np.linalg.norm(tvec) == pytest.approx(3.0)
    intrinsics = poses.Methods("VGA").intrinsics
    exact = poses.ippe_square(truth.corners, intrinsics)
    errors = poses.errors(exact, truth)
    assert errors is not None
    assert errors[0] < 1e-3 and errors[1] < 1e-6
    assert poses.errors(None, truth) is None


def test_each_method_finds_the_tag_s_pose() -> None:
    rng = np.random.default_rng(1)
    rotation, tvec = poses.random_view("HD720", 2.0, rng)
    image, truth = poses.render("HD720", rotation, tvec, 0.7, rng)
    found = poses.Methods("HD720").poses(image)
    assert set(found) == set(poses.METHODS)
    for name, pose in found.items():
        errors = poses.errors(pose, truth)
        assert errors is not None, name
        assert errors[0] < 5.0 and errors[1] < 5.0, name
    service, opencv = poses.errors(found["service"], truth), poses.errors(found["opencv"], truth)
    assert service is not None and opencv is not None
    assert service[0] < opencv[0]


def test_a_small_run_reports_every_distance_the_drives_the_cost_and_the_goals() -> None:
    plan = poses.Plan(frames=1, drives=1, drive_frames=2, cost_tags=2)
    report = poses.run(plan)
    for resolution in poses.CAMERAS:
        rows = report["accuracy"][resolution]
        assert [row["distance_m"] for row in rows] == list(poses.DISTANCES_M)
        assert rows[0]["service"]["found"] == 1
        drives = report["drives"][resolution]
        assert drives["poses"] <= 2
        assert drives["flipped_with_memory"] <= drives["poses"]
    assert report["cost"]["tags"] == 2
    assert math.isfinite(report["cost"]["added_ms"])
    assert len(report["goals"]) == 6
    text = poses.format_report(report)
    assert "### HD720" in text and "### Goals" in text
