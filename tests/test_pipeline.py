"""The pipeline: frame to grey to detections to per-tag geometry to the selection; and it keeps
no state per frame size (a camera that changes size costs no memory)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import numpy.typing as npt
import pytest

from tests.helpers import pipeline_of
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.pipeline import TagFinder, intrinsics_from_settings, observe
from zenoh_perception.settings import Settings
from zenoh_perception.tags.geometry import closeness_from_area
from zenoh_perception.tags.pose import Intrinsics
from zenoh_perception.tags.selection import NO_TAG, Metric, Policy, selected_message
from zenoh_perception.wire.frames import ENCODINGS, Frame, RawFrameMeta, decode_raw_frame
from zenoh_perception_bench.poses import project, tag_rotation
from zenoh_perception_bench.scene import render_markers
from zenoh_perception_bench.scene.lookalikes import lookalike_frame


def _frames(count: int, first: int) -> list[tuple[bytes, bytes]]:
    """``count`` BGRA frames, each of a size no other frame has (from ``first``)."""
    frames = []
    for i in range(count):
        width, height = 320 + 2 * (first + i), 240 + (first + i)
        side = 60.0
        corners = np.array([[40, 40], [40 + side, 40], [40 + side, 40 + side], [40, 40 + side]])
        image = render_markers(width, height, [(5, corners)])
        frames.append((image.tobytes(), RawFrameMeta(width, height).to_msgpack()))
    return frames


def test_frames_of_ever_new_sizes_do_not_grow_memory() -> None:
    pipeline = pipeline_of(Settings())
    warm_up, measured = _frames(10, 0), _frames(120, 10)
    tracemalloc.start()
    try:
        for payload, meta in warm_up:
            assert pipeline.process(decode_raw_frame(payload, meta)).selected.tag_id == 5
        before, _peak = tracemalloc.get_traced_memory()
        for payload, meta in measured:
            assert pipeline.process(decode_raw_frame(payload, meta)).selected.tag_id == 5
        after, _peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # A cache of one buffer per frame size would hold 120 frames of 77-140 kB or more each.
    assert after - before < 1 << 20


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _frame(markers: list[tuple[int, npt.NDArray[np.float64]]], width: int = 640) -> Frame:
    height = width * 3 // 4
    image = render_markers(width, height, markers)
    return decode_raw_frame(image.tobytes(), RawFrameMeta(width, height).to_msgpack())


#: A big (close) tag 7 off centre, a small (far) tag 3 on the centre of a 640 x 480 frame.
TWO_TAGS = [(7, _square(40, 40, 200)), (3, _square(300, 220, 40))]


def test_every_tag_is_observed_and_the_closest_selected() -> None:
    analysis = pipeline_of(Settings()).process(_frame(TWO_TAGS))
    tags = {tag.tag_id: tag for tag in analysis.tags}
    assert sorted(tags) == [3, 7]
    assert (tags[7].x, tags[7].y) == pytest.approx((139.5, 139.5), abs=0.75)
    assert tags[7].area_px == pytest.approx(200 * 200, rel=0.03)
    assert tags[7].closeness == pytest.approx(1 - np.sqrt(200 * 200 / (640 * 480)), abs=0.01)
    assert all(tag.metric == Metric.AREA and tag.distance_m is None for tag in analysis.tags)
    assert analysis.selected == tags[7].message()
    assert analysis.convert_ms >= 0.0 and analysis.detect_ms >= 0.0


def test_each_tag_names_its_dictionary_and_several_are_read_at_once() -> None:
    assert {t.dictionary for t in pipeline_of(Settings()).process(_frame(TWO_TAGS)).tags} == {
        "DICT_4X4_50"
    }
    meta = RawFrameMeta(640, 480)
    apriltag = render_markers(
        640, 480, [(23, _square(400, 300, 120))], dictionary="DICT_APRILTAG_16h5"
    )
    both = np.minimum(render_markers(640, 480, TWO_TAGS[:1]), apriltag)
    frame = decode_raw_frame(both.tobytes(), meta.to_msgpack())
    pipeline = pipeline_of(Settings.from_flat(dictionary="DICT_APRILTAG_16h5, DICT_4X4_50"))
    found = sorted((t.tag_id, t.dictionary) for t in pipeline.process(frame).tags)
    assert found == [(7, "DICT_4X4_50"), (23, "DICT_APRILTAG_16h5")]


def test_the_center_policy_selects_the_tag_on_the_centre() -> None:
    analysis = pipeline_of(Settings.from_flat(policy="center")).process(_frame(TWO_TAGS))
    assert analysis.selected.tag_id == 3


def test_no_tag_selects_the_dummy() -> None:
    analysis = pipeline_of(Settings()).process(_frame([]))
    assert (analysis.tags, analysis.selected) == ((), NO_TAG)


def test_tags_smaller_than_min_tag_side_px_are_left_out() -> None:
    analysis = pipeline_of(Settings.from_flat(min_tag_side_px=60.0)).process(_frame(TWO_TAGS))
    assert [tag.tag_id for tag in analysis.tags] == [7]


def test_intrinsics_and_a_tag_size_give_a_pose_and_the_distance_metric() -> None:
    settings = Settings.from_flat(
        metric="distance",
        max_range_m=4.0,
        tag_sizes=((7, 0.5),),
        camera_fx=500.0,
        camera_fy=500.0,
        camera_cx=319.5,
        camera_cy=239.5,
    )
    analysis = pipeline_of(settings).process(_frame(TWO_TAGS))
    tags = {tag.tag_id: tag for tag in analysis.tags}
    # 200 px for 0.5 m at fx = 500: 1.25 m in front of the camera, a little to the side
    assert tags[7].tvec is not None and tags[7].tvec[2] == pytest.approx(1.25, rel=0.02)
    assert tags[7].distance_m == pytest.approx(float(np.linalg.norm(tags[7].tvec)))
    assert tags[7].metric == Metric.DISTANCE
    assert tags[7].closeness == pytest.approx(float(np.linalg.norm(tags[7].tvec)) / 4.0)
    assert tags[3].metric == Metric.AREA and tags[3].distance_m is None  # no size for id 3
    assert analysis.selected.tag_id == 7  # a distance ranks before an area


def test_the_intrinsics_may_change_at_run_time() -> None:
    pipeline = pipeline_of(Settings.from_flat(tag_size_m=0.2))
    assert pipeline.intrinsics is None
    assert pipeline.process(_frame(TWO_TAGS)).tags[0].distance_m is None
    pipeline.intrinsics = Intrinsics(500.0, 500.0, 319.5, 239.5)
    assert all(tag.distance_m is not None for tag in pipeline.process(_frame(TWO_TAGS)).tags)


class _Fixed(Detector):
    """A detector that reports the same detections whatever the frame."""

    def __init__(self, *detections: Detection) -> None:
        self.detections = list(detections)
        self.frames: list[tuple[int, ...]] = []

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        self.frames.append(gray.shape)
        return list(self.detections)


def test_the_given_detector_sees_the_grey_frame_and_its_detections_are_used() -> None:
    quad = _square(10, 10, 20).astype(np.float32)
    detector = _Fixed(Detection(42, quad))
    analysis = pipeline_of(Settings.from_flat(verify=False), detector).process(
        _frame([], width=320)
    )
    assert detector.frames == [(240, 320)]
    (tag,) = analysis.tags
    assert (tag.tag_id, tag.x, tag.y, tag.area_px) == (42, 20.0, 20.0, 400.0)
    assert tag.corners == tuple((float(x), float(y)) for x, y in quad)


def test_observe_is_the_geometry_of_one_detection() -> None:
    detection = Detection(5, _square(100, 100, 64).astype(np.float32))
    tag = observe(detection, 640, 480, Settings().selection)
    assert (tag.tag_id, tag.x, tag.y) == (5, 132.0, 132.0)
    assert tag.closeness == pytest.approx(closeness_from_area(64 * 64, 640, 480))
    assert intrinsics_from_settings(Settings().selection) is None


def test_tag_finder_filters_by_side_and_times_the_conversion() -> None:
    small = Detection(1, _square(0, 0, 10).astype(np.float32))
    large = Detection(2, _square(50, 50, 30).astype(np.float32))
    finder = TagFinder(_Fixed(small, large), min_side_px=20.0)
    detections, convert_s = finder.find(_frame([], width=320))
    assert [d.tag_id for d in detections] == [2]
    assert convert_s >= 0.0


def test_begin_judges_only_the_selected_tag_and_finish_the_others(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    judged: list[int] = []
    check = Verifier.check

    def counted(self: Verifier, gray: npt.NDArray[np.uint8], detection: Detection) -> str | None:
        judged.append(detection.tag_id)
        return check(self, gray, detection)

    monkeypatch.setattr(Verifier, "check", counted)
    pipeline = pipeline_of(Settings())
    pending = pipeline.begin(_frame(TWO_TAGS))
    assert pending.selected.tag_id == 7
    assert judged == [7]  # the closest, kept: the tag is known before 3 is read
    analysis = pending.finish()
    assert sorted(judged) == [3, 7]
    assert sorted(t.tag_id for t in analysis.tags) == [3, 7]
    assert analysis.selected == pending.selected


def _lookalikes_and_a_tag() -> Frame:
    """Key-caps OpenCV reads as DICT_4X4_50 ids (about 36 px), larger than the one true 26 px
    tag 3 pasted on a white patch in the top-left corner."""
    image = lookalike_frame("keys", "DICT_4X4_50", np.random.default_rng(7))
    tag = render_markers(640, 480, [(3, _square(20, 20, 26))])
    image[:70, :70] = tag[:70, :70]
    return Frame(image, ENCODINGS["bgra8"], None, "test", None)


def test_a_vetoed_candidate_hands_the_selection_to_the_next() -> None:
    unverified = pipeline_of(Settings.from_flat(verify=False)).process(_lookalikes_and_a_tag())
    # without the veto a look-alike, closer than the tag, would be selected
    assert unverified.selected.tag_id != 3 and len(unverified.tags) > 1
    pipeline = pipeline_of(Settings())
    pending = pipeline.begin(_lookalikes_and_a_tag())
    assert pending.selected.tag_id == 3
    analysis = pending.finish()
    assert [t.tag_id for t in analysis.tags] == [3]
    assert analysis.selected == pending.selected
    assert sum(pipeline.vetoed.values()) == len(unverified.tags) - 1


@pytest.mark.parametrize("policy", ["closest", "center"])
def test_begin_selects_what_the_whole_frame_screened_selects(policy: str) -> None:
    rng = np.random.default_rng(3)
    settings = Settings.from_flat(policy=policy)
    staged, whole = pipeline_of(settings), pipeline_of(settings)
    for kind in ("keys", "text", "tiles", "other_family"):
        frame = Frame(
            lookalike_frame(kind, "DICT_4X4_50", rng), ENCODINGS["bgra8"], None, "test", None
        )
        found, _ = whole.find(frame)  # every detection screened, then selected
        expected = selected_message(
            tuple(observe(d, 640, 480, settings.selection) for d in found), 640, 480, Policy(policy)
        )
        assert staged.begin(frame).selected == expected


def _opencv_corners(frame: Frame) -> dict[int, npt.NDArray[np.float32]]:
    analysis = pipeline_of(Settings.from_flat(refine_corners=False)).process(frame)
    return {tag.tag_id: np.array(tag.corners, np.float32) for tag in analysis.tags}


def test_published_corners_are_refined_and_the_tags_found_are_opencv_s() -> None:
    # exact renders: the true outer corners are the squares drawn
    truth = dict(TWO_TAGS)
    frame = _frame(TWO_TAGS)
    opencv = _opencv_corners(frame)
    analysis = pipeline_of(Settings()).process(frame)
    assert sorted(tag.tag_id for tag in analysis.tags) == sorted(opencv)
    for tag in analysis.tags:
        refined = np.array(tag.corners)
        worst = np.linalg.norm(refined - truth[tag.tag_id], axis=1).max()
        assert worst < 0.1 < np.linalg.norm(opencv[tag.tag_id] - truth[tag.tag_id], axis=1).max()
        assert (tag.x, tag.y) == pytest.approx(tuple(refined.mean(axis=0)))


def test_refinement_moves_a_detector_s_corners_onto_the_edges_unless_switched_off() -> None:
    truth = _square(100, 100, 120)
    frame = _frame([(7, truth)])
    given = (truth + 0.7).astype(np.float32)  # a detector's corners, 0.7 px off
    refined = pipeline_of(Settings.from_flat(verify=False), _Fixed(Detection(7, given))).process(
        frame
    )
    assert np.linalg.norm(np.array(refined.tags[0].corners) - truth, axis=1).max() < 0.1
    unrefined = pipeline_of(
        Settings.from_flat(verify=False, refine_corners=False), _Fixed(Detection(7, given))
    )
    assert unrefined.process(frame).tags[0].corners == tuple(map(tuple, given.tolist()))


def test_an_ambiguous_pose_is_kept_but_not_ranked_by_under_the_distance_metric() -> None:
    camera = Intrinsics(500.0, 500.0, 319.5, 239.5)
    settings = Settings.from_flat(
        metric="distance",
        tag_size_m=0.2,
        camera_fx=camera.fx,
        camera_fy=camera.fy,
        camera_cx=camera.cx,
        camera_cy=camera.cy,
    )

    def seen(distance: float, yaw: float) -> Detection:
        corners = project(
            tag_rotation(yaw, 5.0, 10.0), np.array([0.1, 0.05, distance]), camera.matrix()
        )
        return Detection(1, corners.astype(np.float32))

    far = observe(seen(8.0, 10.0), 640, 480, settings.selection, camera)
    assert far.ambiguous and far.pose_errors is not None and far.distance_m is not None
    assert far.metric == Metric.AREA
    near = observe(seen(1.0, 40.0), 640, 480, settings.selection, camera)
    assert not near.ambiguous and near.metric == Metric.DISTANCE
