"""Scoring against a generated scene's truth (Tally) and against a person's labels (Score)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.bench.conftest import square
from zenoh_perception.detect.types import Detection
from zenoh_perception_bench.manifest import Item
from zenoh_perception_bench.scene import CameraModel, Effects, MarkerPose, Scene, SceneGenerator
from zenoh_perception_bench.scoring import BUCKETS, Score, Tally, rounded, score, size_bucket


def two_tags() -> Scene:
    camera = CameraModel.named("VGA")
    return SceneGenerator(camera, seed=1, effects=Effects.clean()).scene_from_poses(
        [MarkerPose(3, 0.2, (-0.3, 0.0, 1.5)), MarkerPose(9, 0.2, (0.3, 0.0, 1.5))]
    )


def test_score_counts_hits_misses_and_false_positives() -> None:
    scene = two_tags()
    first = scene.markers[0]
    exact = Detection(first.tag_id, first.corners.astype(np.float32))
    wrong_place = Detection(9, first.corners.astype(np.float32))  # id 9, but where 3 is
    found, visible, false_pos, centre, distance = score(scene, [exact, wrong_place])
    assert (found, visible, false_pos) == (1, 2, 1)
    assert centre == [pytest.approx(0.0, abs=1e-4)]
    assert distance[0] == pytest.approx(0.0, abs=1e-3)
    # the same tag twice is found once, and is not false
    assert score(scene, [exact, exact])[:3] == (1, 2, 0)


def test_a_tally_sums_frames_and_passes() -> None:
    scene = two_tags()
    first = scene.markers[0]
    exact = Detection(first.tag_id, first.corners.astype(np.float32))
    tally = Tally()
    tally.add(scene, [exact], 2.0)
    tally.add(scene, [], 4.0)
    summary = tally.summary()
    assert summary["recall"] == pytest.approx(0.25)
    assert summary["median_ms"] == pytest.approx(3.0)
    assert (summary["found"], summary["visible"], summary["frames"]) == (1, 4, 2)
    assert summary["centre_error_px"] == pytest.approx(0.0, abs=1e-3)
    other = Tally()
    other.add(scene, [exact, Detection(9, first.corners.astype(np.float32))], None)  # no time
    tally.extend(other)
    summary = tally.summary()
    assert (summary["found"], summary["visible"], summary["false_positives"]) == (2, 6, 1)
    assert summary["frames"] == 2  # frames timed


def test_an_empty_tally_has_no_figures() -> None:
    summary = Tally().summary()
    assert summary["frames"] == 0
    assert summary["median_ms"] is summary["centre_error_px"] is None
    assert summary["recall"] == 1.0  # nothing to find, nothing missed


def test_score_counts_labels_unknown_and_false_ids() -> None:
    item = Item("x", "image", "DICT_4X4_50", {1: 2}, unknown_markers=1)
    quad = square(0, 0, 30).astype(np.float32)
    result = Score()
    result.add(item, [Detection(i, quad) for i in (1, 1, 1, 4, 5)], 2.0)
    assert (result.found, result.unverified, result.false_ids) == (2, 1, 2)
    assert result.labelled == 2
    summary = result.summary()
    assert summary["buckets"][size_bucket(30.0)] == 2
    assert list(summary["buckets"]) == list(BUCKETS)
    assert summary["false_examples"] == {"4": 1, "5": 1}
    pooled = Score()
    pooled.extend(result)
    pooled.extend(result)
    assert (pooled.frames, pooled.found, pooled.false_ids) == (2, 4, 4)
    assert pooled.summary()["false_examples"] == {"4": 2, "5": 2}


@pytest.mark.parametrize(
    ("side", "bucket"),
    [(12.0, "0-24 px"), (24.0, "24-48 px"), (100.0, "96-192 px"), (500.0, ">= 192 px")],
)
def test_size_buckets(side: float, bucket: str) -> None:
    assert size_bucket(side) == bucket
    assert bucket in BUCKETS


def test_rounded_is_a_float_of_three_decimals() -> None:
    value = rounded(np.float64(1.23456))
    assert value == 1.235
    assert type(value) is float


def _at(tag: int, side: float) -> Detection:
    return Detection(tag, square(10, 10, side).astype(np.float32))


def test_a_score_keeps_missed_ids_and_false_ids_by_size() -> None:
    labels = Item("x", "image", "DICT_4X4_50", {3: 2, 7: 1})
    s = Score()
    s.add(labels, [_at(3, 100.0), _at(9, 30.0)], 1.0)
    s.add(labels, [_at(7, 100.0), _at(3, 100.0), _at(3, 100.0)], 1.0)
    assert s.missed == {3: 1, 7: 1}
    assert s.false_buckets[size_bucket(30.0)] == 1
    summary = s.summary()
    assert summary["missed"] == {"3": 1, "7": 1}
    assert summary["found_ids"] == {"3": 3, "7": 1}
    assert summary["share_found"] == round(4 / 6, 4)
    assert summary["false_buckets"][size_bucket(30.0)] == 1
    pooled = Score()
    pooled.extend(s)
    pooled.extend(s)
    assert pooled.missed == {3: 2, 7: 2}
    assert pooled.false_buckets[size_bucket(30.0)] == 2
    assert Score().summary()["share_found"] is None


def test_a_video_s_markers_count_only_in_the_frames_they_are_whole_in() -> None:
    item = Item("v", "video", "DICT_4X4_50", {3: 1, 7: 1}, in_view={7: ((2, 3),)})
    s = Score()
    for index in range(5):
        s.add(item.frame(index), [_at(3, 100.0), _at(7, 100.0)], 1.0)
    assert (s.labelled, s.found, s.false_ids, s.unverified) == (7, 7, 0, 3)
    assert item.frame(0).markers == {3: 1} and item.frame(2).markers == {3: 1, 7: 1}
    missed = Score()
    for index in range(5):
        missed.add(item.frame(index), [], 1.0)
    assert missed.missed == {3: 5, 7: 2}
    assert Item("s", "image", "DICT_4X4_50", {3: 1}).frame(4).markers == {3: 1}
