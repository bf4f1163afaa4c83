"""The detectors side by side: same frames, order rotating, one tally each."""

from __future__ import annotations

import itertools
from collections import Counter

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from tests.bench.conftest import square
from zenoh_perception.detect.types import Detection
from zenoh_perception.settings import Settings
from zenoh_perception_bench.framesets import Plan, board_frames
from zenoh_perception_bench.runners import (
    BEST,
    BEST_SETTING,
    PAIR,
    SHOWN,
    Baseline,
    Best,
    Project,
    board_case,
    compare,
    detector_parameters,
    pair,
    rotation,
)
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator, render_markers


def test_rotation_puts_each_first_in_turn() -> None:
    assert rotation("abc", 0) == ["a", "b", "c"]
    assert rotation("abc", 1) == ["b", "c", "a"]
    assert rotation(PAIR, 1) == [PAIR[1], PAIR[0]]
    assert rotation("a", 3) == ["a"]


@pytest.mark.parametrize("n", [2, 3, 4, 5, 7, 8])
def test_rotation_balances_who_follows_whom(n: int) -> None:
    order = list(range(n))
    cycle = n if n % 2 == 0 else 2 * n
    rows = [rotation(order, index) for index in range(cycle)]
    assert all(sorted(row) == order for row in rows)
    firsts = Counter(row[0] for row in rows)
    assert set(firsts.values()) == {cycle // n}
    follows = Counter((a, b) for row in rows for a, b in itertools.pairwise(row))
    assert len(follows) == n * (n - 1)  # every ordered pair, each as often
    assert len(set(follows.values())) == 1
    assert rotation(order, cycle + 1) == rows[1]


class Recorder:
    """A runner that finds nothing and says when it ran."""

    def __init__(self, name: str, calls: list[str]) -> None:
        self.name = name
        self.calls = calls

    def run(self, image: npt.NDArray[np.uint8]) -> tuple[list[Detection], float]:
        self.calls.append(self.name)
        return [], 1.0


def test_compare_runs_every_runner_on_every_frame_in_rotating_order() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=5, effects=Effects.clean())
    scenes = [generator.random_scene(2, 0) for _ in range(3)]
    calls: list[str] = []
    tallies = compare(scenes, [Recorder("a", calls), Recorder("b", calls)], None, "test")
    assert calls == ["a", "b", "b", "a", "a", "b"]
    assert [len(t.times_ms) for t in tallies] == [3, 3]
    assert tallies[0].visible == sum(
        1 for s in scenes for m in s.markers if m.visible and not m.occluded
    )


def test_baseline_and_project_find_the_tags_of_a_clean_frame() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=2, effects=Effects.clean())
    scene = generator.random_scene(3, 0)
    wanted = sorted(m.tag_id for m in scene.markers if m.visible and not m.occluded)
    assert wanted
    for runner in (Baseline(), Project()):
        detections, ms = runner.run(scene.image)
        assert sorted(d.tag_id for d in detections) == wanted
        assert ms > 0.0


def test_the_pair_runs_the_service_s_detector_with_its_settings() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=2, effects=Effects.clean())
    image = generator.random_scene(3, 0).image
    runners = pair("DICT_4X4_50", Settings.from_flat(min_tag_side_px=1000.0).detection)
    assert tuple(runners) == PAIR
    assert runners["opencv"].run(image)[0]  # OpenCV's default sees the tags...
    assert runners["service"].run(image)[0] == []  # ...the service drops them: too small


def test_the_board_case_gives_each_detector_its_figures_frame_by_frame() -> None:
    frames = board_frames(Plan(board_squares=(12,)))[:2]
    after = SceneGenerator(CameraModel.named("HD720"), seed=2, effects=Effects.clean())
    case = board_case(frames, after.random_scene(2, 0).image, None)
    assert [(row["kind"], row["square_px"]) for row in case["frames"]] == [
        (f.kind, f.square) for f in frames
    ]
    for row in case["frames"]:
        for name in PAIR:
            assert row[name]["found"] == row[name]["tags"] == 2 and row[name]["false"] == 0
    assert set(case["after_storm_ms"]) == set(PAIR)
    assert case["plain_frame_cost_ms"] > 0


def test_the_best_setting_is_the_most_thorough_one_measured() -> None:
    assert dict(BEST_SETTING) == {
        "adaptiveThreshWinSizeMin": 3,
        "adaptiveThreshWinSizeMax": 53,
        "adaptiveThreshWinSizeStep": 4,
        "minMarkerPerimeterRate": 0.02,
    }
    params = Best().parameters
    assert (
        params.adaptiveThreshWinSizeMin,
        params.adaptiveThreshWinSizeMax,
        params.adaptiveThreshWinSizeStep,
    ) == (3, 53, 4)
    assert params.minMarkerPerimeterRate == pytest.approx(0.02)
    # everything else is OpenCV's default, as the baseline's parameters are
    default, baseline = cv2.aruco.DetectorParameters(), Baseline().parameters
    for key in ("minMarkerDistanceRate", "cornerRefinementMethod", "errorCorrectionRate"):
        assert getattr(params, key) == getattr(default, key) == getattr(baseline, key)
    assert baseline.adaptiveThreshWinSizeMax == default.adaptiveThreshWinSizeMax == 23
    assert baseline.minMarkerPerimeterRate == pytest.approx(0.03)


def test_a_parameter_opencv_does_not_have_is_refused() -> None:
    with pytest.raises(AttributeError, match="adaptiveThreshWinSize"):
        detector_parameters({"adaptiveThreshWinSize": 3})


def test_the_best_setting_finds_a_tag_too_small_for_the_default() -> None:
    # a 24 px tag: perimeter 96 px, under 3 % of the image's 4000 px side, over 2 %
    image = render_markers(4000, 200, [(7, square(1000, 60, 24))])
    assert Baseline().run(image)[0] == []
    detections, ms = Best().run(image)
    assert [d.tag_id for d in detections] == [7]
    assert ms > 0.0


def test_with_best_the_runners_are_opencv_s_default_its_best_setting_and_the_service() -> None:
    runners = pair("DICT_4X4_50", Settings().detection, best=True)
    assert tuple(runners) == SHOWN == ("opencv", BEST, "service")
    assert isinstance(runners[BEST], Best)
    assert type(runners["opencv"]) is Baseline
    assert {k for k in SHOWN if k != BEST} == set(PAIR)
