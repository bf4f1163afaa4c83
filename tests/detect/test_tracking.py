"""The tracking detector: OpenCV decides every marker; whole frames are read only when needed."""

from __future__ import annotations

from collections import Counter

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.tracking import TrackingConfig, TrackingDetector
from zenoh_perception.detect.types import Detection
from zenoh_perception.errors import SettingsError
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator, render_markers

W, H = 640, 480


def square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def gray(image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    return np.ascontiguousarray(image[:, :, 1])  # rendered tags are grey: any channel


def ids(detections: list[Detection]) -> Counter[int]:
    return Counter(d.tag_id for d in detections)


def test_independent_frames_are_each_scanned_and_match_opencv() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=11, effects=Effects.realistic())
    tracking = TrackingDetector("DICT_4X4_50")
    opencv = OpenCvDetector("DICT_4X4_50")
    for _ in range(6):
        frame = generator.random_scene(4, 2).gray()
        found = tracking.detect(frame)
        expected = opencv.detect(frame)
        assert ids(found) == ids(expected)
        for a, b in zip(
            sorted(found, key=lambda d: d.tag_id),
            sorted(expected, key=lambda d: d.tag_id),
            strict=True,
        ):
            np.testing.assert_array_equal(a.corners, b.corners)
    assert tracking.counters["scans"] == tracking.counters["frames"] == 6


def test_a_still_followed_scene_is_read_in_regions_between_scans() -> None:
    frame = gray(render_markers(W, H, [(3, square(100, 100, 80)), (7, square(400, 250, 60))]))
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=4))
    results = [tracking.detect(frame) for _ in range(8)]
    assert all(ids(r) == Counter({3: 1, 7: 1}) for r in results)
    # frames 1 and 5 scanned (first, then the period), the others followed in regions
    assert tracking.counters["scans"] == 2
    assert tracking.counters["followed"] == 6
    # the corners found in a region are where the whole-frame detector puts them
    whole = {d.tag_id: d.corners for d in OpenCvDetector("DICT_4X4_50").detect(frame)}
    for detection in results[1]:
        np.testing.assert_allclose(detection.corners, whole[detection.tag_id], atol=1e-4)


def test_following_leaves_opencv_s_process_wide_thread_count_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # several streams' workers may be inside OpenCV at once: a read that changed the count
    # would change it under the others
    changes: list[int] = []
    monkeypatch.setattr(cv2, "setNumThreads", changes.append)
    frame = gray(render_markers(W, H, [(3, square(100, 100, 80)), (7, square(400, 250, 60))]))
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=4))
    for _ in range(4):
        tracking.detect(frame)
    assert tracking.counters["followed"] == 3
    assert changes == []


def test_a_moving_tag_is_followed_and_a_jump_is_found_by_a_rescan() -> None:
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=100))
    for step in range(6):  # 6 px a frame: followed in its region
        frame = gray(render_markers(W, H, [(5, square(100 + 6 * step, 120, 70))]))
        found = tracking.detect(frame)
        assert [d.tag_id for d in found] == [5]
        assert found[0].corners[0, 0] == pytest.approx(100 + 6 * step, abs=1.0)
    assert tracking.counters["scans"] == 1
    # a jump far beyond the region: something appeared away from it, scanned on the same frame
    frame = gray(render_markers(W, H, [(5, square(450, 300, 70))]))
    found = tracking.detect(frame)
    assert [d.tag_id for d in found] == [5]
    assert tracking.counters["appearances"] == 1
    assert tracking.counters["scans"] == 2


def test_a_marker_missing_from_its_region_makes_a_rescan() -> None:
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=100))
    frame = gray(render_markers(W, H, [(5, square(100, 120, 70)), (6, square(400, 120, 70))]))
    tracking.detect(frame)
    hidden = frame.copy()
    hidden[130:180, 110:160] = 0  # its inside covered: not a marker any more
    assert ids(tracking.detect(hidden)) == Counter({6: 1})
    assert tracking.counters["lost_rescans"] == 1


def test_a_tag_entering_a_followed_scene_is_reported_within_the_period() -> None:
    period = 4
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=period))
    base = [(1, square(60, 60, 60))]
    for _ in range(2):
        tracking.detect(gray(render_markers(W, H, base)))
    with_new = gray(render_markers(W, H, [*base, (2, square(420, 300, 40))]))
    frames_until_seen = next(k for k in range(1, period + 1) if 2 in ids(tracking.detect(with_new)))
    assert frames_until_seen <= period


def test_a_scene_cut_is_scanned_at_once() -> None:
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=100))
    tracking.detect(gray(render_markers(W, H, [(1, square(60, 60, 60))])))
    other = render_markers(W, H, [(2, square(300, 200, 90))])
    other[:, :, :3] //= 3  # a darker, different scene
    found = tracking.detect(gray(other))
    assert ids(found) == Counter({2: 1})
    assert tracking.counters["scene_cuts"] == 1


def test_a_region_reports_new_markers_down_to_a_third_of_the_followed_one() -> None:
    # a followed 240 px marker (perimeter 960 px): its region is read for perimeters of 320
    # px or more, so a new 96 px marker beside it is reported at once and a 50 px one is left
    # to the next scan
    config = TrackingConfig(full_scan_period=3, glimpse=False)
    tracking = TrackingDetector("DICT_4X4_50", config)
    followed = (8, square(200, 120, 240))
    tracking.detect(gray(render_markers(W, H, [followed])))
    frame = gray(
        render_markers(W, H, [followed, (2, square(455, 200, 96)), (5, square(470, 50, 50))])
    )
    assert ids(tracking.detect(frame)) == Counter({8: 1, 2: 1})
    assert tracking.counters["followed"] == 1
    assert ids(tracking.detect(frame)) == Counter({8: 1, 2: 1})
    assert ids(tracking.detect(frame)) == Counter({8: 1, 2: 1, 5: 1})  # the period's scan
    assert tracking.counters["scans"] == 2


def test_a_flickering_tag_is_searched_in_its_region_while_it_coasts() -> None:
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=100))
    with_tag = gray(render_markers(W, H, [(4, square(200, 150, 50)), (6, square(450, 300, 60))]))
    without = with_tag.copy()
    without[150:200, 200:250] = 255  # tag 4 washed out (glare) on one frame
    tracking.detect(with_tag)
    assert ids(tracking.detect(without)) == Counter({6: 1})  # missed: one rescan, it coasts
    scans = tracking.counters["scans"]
    assert ids(tracking.detect(with_tag)) == Counter({4: 1, 6: 1})
    assert tracking.counters["scans"] == scans  # found again in its region, no scan


def test_still_empty_scene_is_not_read_again_until_the_period() -> None:
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=5))
    empty = gray(render_markers(W, H, []))
    for _ in range(10):
        assert tracking.detect(empty) == []
    assert tracking.counters["scans"] == 2
    assert tracking.counters["still_skips"] == 8


def test_video_finds_at_least_what_opencv_finds_every_frame() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=5, effects=Effects.realistic())
    tracking = make_detector("tracking", "DICT_4X4_50")
    opencv = OpenCvDetector("DICT_4X4_50")
    found = expected = 0
    for scene in generator.drive(60, fps=30.0, n_tags=3, n_distractors=0):
        frame = scene.gray()
        truth = set(scene.ids)
        found += sum(d.tag_id in truth for d in tracking.detect(frame))
        expected += sum(d.tag_id in truth for d in opencv.detect(frame))
    assert expected > 0
    assert found >= expected
    assert isinstance(tracking, TrackingDetector)
    assert tracking.counters["scans"] < tracking.counters["frames"]


def test_a_large_marker_is_followed_in_a_region_read_at_a_smaller_scale() -> None:
    frame = gray(render_markers(W, H, [(8, square(150, 80, 300))]))
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=100))
    scanned = tracking.detect(frame)
    followed = tracking.detect(frame)
    assert tracking.counters["followed"] == 1
    assert [d.tag_id for d in followed] == [8]
    # read at a quarter of its size, corners refined at full resolution
    np.testing.assert_allclose(followed[0].corners, scanned[0].corners, atol=1.0)


@pytest.mark.parametrize(
    "config",
    [
        {"full_scan_period": 0},
        {"coast_frames": -1},
        {"scene_cut_level": 300.0},
        {"still_level": -1.0},
    ],
)
def test_config_bounds(config: dict[str, float]) -> None:
    with pytest.raises(SettingsError):
        TrackingConfig(**config)  # type: ignore[arg-type]


def test_a_scene_cut_forgets_where_the_markers_were() -> None:
    tagged = gray(render_markers(W, H, [(3, square(100, 100, 80))], background=40))
    other = gray(render_markers(W, H, [], background=220))  # another scene, no marker
    tracking = TrackingDetector("DICT_4X4_50", TrackingConfig(full_scan_period=100))
    assert ids(tracking.detect(tagged)) == Counter({3: 1})
    assert tracking.detect(other) == []
    assert tracking.counters["scene_cuts"] == 1
    # nothing is left to follow or coast: the still scene is not read again
    assert tracking.detect(other) == []
    assert tracking.counters["still_skips"] == 1
    assert tracking.counters["scans"] == 2
