"""The pipeline: frame to grey to detections to per-tag geometry to the selection; and it keeps
no state per frame size (a camera that changes size costs no memory)."""

from __future__ import annotations

import tracemalloc

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import pipeline_of
from zenoh_perception import pipeline as pipeline_module
from zenoh_perception.detect.coarse import same_answer
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.pipeline import (
    Pipeline,
    TagFinder,
    intrinsics_from_settings,
    observe,
    rank_floor,
    ranked,
)
from zenoh_perception.settings import Settings
from zenoh_perception.tags.corners import MAX_MOVE_CELLS
from zenoh_perception.tags.geometry import closeness_from_area, mean_side
from zenoh_perception.tags.pose import Intrinsics, estimate_pose
from zenoh_perception.tags.selection import (
    NO_TAG,
    Metric,
    Policy,
    TagObservation,
    selected_message,
    selection_key,
)
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


def _posed(**flat: object) -> Settings:
    """Settings with a 20 cm tag and the intrinsics of a 640x480 camera (fx = fy = 500)."""
    intrinsics = {"camera_fx": 500.0, "camera_fy": 500.0, "camera_cx": 319.5, "camera_cy": 239.5}
    return Settings.from_flat(**{"tag_size_m": 0.2, **intrinsics, **flat})


@pytest.mark.parametrize("metric", ["area", "distance"])
def test_poses_follow_the_tag_unless_the_selection_ranks_by_them(
    metric: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = _posed(metric=metric)
    expected = pipeline_of(settings).process(_frame(TWO_TAGS))
    solved: list[int] = []

    def counted(*args: object, **kwargs: object) -> object:
        solved.append(1)
        return estimate_pose(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(pipeline_module, "estimate_pose", counted)
    pending = pipeline_of(settings).begin(_frame(TWO_TAGS))
    # "area": the tag says nothing a pose decides, so no pose is solved before it
    assert len(solved) == (0 if metric == "area" else 2)
    analysis = pending.finish()
    assert len(solved) == 2
    assert pending.selected == expected.selected
    assert analysis.tags == expected.tags
    assert all(tag.distance_m is not None for tag in analysis.tags)


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


def test_a_tag_s_last_clear_pose_chooses_its_ambiguous_pose_s_solution() -> None:
    intrinsics = Intrinsics(500.0, 500.0, 319.5, 239.5)
    # a 12 px tag 8 m away nearly facing the camera: IPPE's best is the exact pose, its
    # mirror nearly as good
    far = project(tag_rotation(10.0, 5.0, 10.0), np.array([0.1, 0.05, 8.0]), intrinsics.matrix())
    alone = estimate_pose(far, 0.2, intrinsics)
    assert alone is not None and alone.ambiguous and alone.other is not None
    # the same tag near, turned as the mirror solution: a clear pose
    mirror, _ = cv2.Rodrigues(np.array(alone.other[0]))
    near = project(np.asarray(mirror, np.float64), np.array([0.1, 0.05, 1.5]), intrinsics.matrix())
    detector = _Fixed()
    pipeline = pipeline_of(_posed(verify=False), detector)

    def tag(corners: npt.NDArray[np.float64]) -> TagObservation:
        detector.detections = [Detection(7, corners.astype(np.float32))]
        (observed,) = pipeline.process(_frame([], width=640)).tags
        return observed

    first = tag(far)
    assert first.ambiguous and first.rvec == pytest.approx(alone.rvec, abs=1e-3)
    assert not tag(near).ambiguous
    # the far tag again: the stream's last clear pose picks the mirror, still marked
    again = tag(far)
    assert again.ambiguous and again.rvec == pytest.approx(alone.other[0], abs=1e-3)
    assert again.pose_errors is not None and again.pose_errors[0] > again.pose_errors[1]


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


def test_only_the_tags_the_selection_needs_are_refined_before_the_tag(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    refined: list[int] = []
    refine = pipeline_module.refined

    def counted(gray: npt.NDArray[np.uint8], detection: Detection) -> Detection:
        refined.append(detection.tag_id)
        return refine(gray, detection)

    monkeypatch.setattr(pipeline_module, "refined", counted)
    # the closest is clearly larger than the others: no other can rank before it refined
    tags = [(7, _square(40, 40, 200)), (3, _square(300, 220, 40)), (5, _square(450, 60, 60))]
    pending = pipeline_of(Settings()).begin(_frame(tags))
    assert pending.selected.tag_id == 7
    assert refined == [7]
    analysis = pending.finish()
    assert sorted(refined) == [3, 5, 7]  # every kept tag, after the tag
    assert analysis.selected == analysis.tags[[t.tag_id for t in analysis.tags].index(7)].message()


def test_ranked_is_sorted_order_asking_only_for_the_keys_that_may_come_next() -> None:
    keys = {0: (1, 0.5), 1: (1, 0.2), 2: (1, 0.9), 3: (1, 0.2)}
    floors = {0: (1.0, 0.45), 1: (1.0, 0.1), 2: (1.0, 0.8), 3: (1.0, 0.15)}
    asked: list[int] = []

    def key(index: int) -> tuple[float, ...]:
        asked.append(index)
        return keys[index]

    order = ranked(4, key, [floors[i] for i in range(4)])
    assert next(order) == 1  # a tie with 3: the lower index, as sorted() leaves it
    assert sorted(asked) == [1, 3]  # 0 and 2 cannot rank before 1
    assert [*order] == [3, 0, 2] == sorted(range(4), key=keys.__getitem__)[1:]
    assert [*ranked(4, keys.__getitem__, None)] == [1, 3, 0, 2]


@given(
    st.tuples(st.floats(20, 600), st.floats(20, 400)),
    st.floats(8, 150),
    st.floats(0.5, 2.0),
    st.lists(st.floats(-1.0, 1.0), min_size=8, max_size=8),
    st.sampled_from(list(Policy)),
)
def test_a_rank_floor_is_never_above_the_refined_tag_s_key(
    corner: tuple[float, float], side: float, stretch: float, moves: list[float], policy: Policy
) -> None:
    x, y = corner
    corners = np.array(
        [[x, y], [x + side * stretch, y + 3], [x + side, y + side], [x - 2, y + side]], np.float32
    )
    detection = Detection(4, corners, "DICT_4X4_50")
    floor = rank_floor(detection, 640, 480, policy, refine=True)
    # the refinement moves each corner at most MAX_MOVE_CELLS of a cell (6 cells across)
    reach = MAX_MOVE_CELLS * mean_side(corners) / 6
    shift = np.array(moves, np.float64).reshape(4, 2)
    shift *= reach / np.maximum(np.linalg.norm(shift, axis=1, keepdims=True), reach)
    moved = Detection(4, (corners + shift).astype(np.float32), "DICT_4X4_50")
    selection = Settings().selection
    key = selection_key(640, 480, policy)(observe(moved, 640, 480, selection))
    assert floor <= key[:2]
    assert floor <= selection_key(640, 480, policy)(observe(detection, 640, 480, selection))[:2]


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


class _Counted(OpenCvDetector):
    """OpenCV's detector, counting its whole-frame reads."""

    reads = 0

    def detect(
        self, gray: npt.NDArray[np.uint8], min_perimeter_px: float = 0.0, *, frame: bool = True
    ) -> list[Detection]:
        self.reads += 1
        return super().detect(gray, min_perimeter_px, frame=frame)


def _hd(markers: list[tuple[int, npt.NDArray[np.float64]]]) -> Frame:
    image = render_markers(1280, 720, markers)
    return Frame(image, ENCODINGS["bgra8"], None, "test", None)


#: A near tag 7 and a farther tag 3 on HD720: the rover closing in.
NEAR = [(7, _square(300.4, 150.2, 160)), (3, _square(900, 400, 40))]


def _coarse_pipeline(settings: Settings | None = None) -> tuple[Pipeline, _Counted]:
    """A pipeline whose stream has just seen the near tag (its next frame is read coarsely,
    where the settings turn the coarse read on)."""
    detector = _Counted()
    pipeline = pipeline_of(settings or Settings.from_flat(coarse_first_read=True), detector)
    pipeline.process(_hd(NEAR))
    return pipeline, detector


def test_a_near_tag_is_answered_from_the_coarse_read_before_the_whole_read() -> None:
    pipeline, detector = _coarse_pipeline()
    assert pipeline.coarse is not None
    before = detector.reads
    frame = _hd([(7, _square(303.7, 151.9, 164)), (3, _square(900, 400, 40))])
    pending = pipeline.begin(frame)
    assert detector.reads == before  # the tag is known before the whole frame is read
    analysis = pending.finish()
    assert detector.reads == before + 1  # ... which follows for the record
    assert pipeline.coarse.counters["answered"] == 1
    whole = pipeline_of(Settings()).process(frame)
    assert pending.selected.tag_id == whole.selected.tag_id == 7
    assert same_answer(pending.selected, whole.selected)
    # the record: the whole read's tags, the published tag as selected, nothing else
    assert analysis.tags == whole.tags
    assert analysis.selected == pending.selected
    assert analysis.whole_selected is None


def test_the_record_does_not_refine_or_judge_the_coarse_read_s_tag_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pipeline, _ = _coarse_pipeline()
    refined: list[int] = []
    judged: list[int] = []
    refine, judge = pipeline_module.refined, Verifier.judge

    def counted_refine(gray: npt.NDArray[np.uint8], detection: Detection) -> Detection:
        refined.append(detection.tag_id)
        return refine(gray, detection)

    def counted_judge(
        self: Verifier, gray: npt.NDArray[np.uint8], detection: Detection
    ) -> str | None:
        judged.append(detection.tag_id)
        return judge(self, gray, detection)

    monkeypatch.setattr(pipeline_module, "refined", counted_refine)
    monkeypatch.setattr(Verifier, "judge", counted_judge)
    frame = _hd([(7, _square(303.7, 151.9, 164)), (3, _square(900, 400, 40))])
    pending = pipeline.begin(frame)
    assert (refined, judged) == ([7], [7])  # the tag, from the coarse read
    analysis = pending.finish()
    # the whole read found tag 7 with the crop's corners: only tag 3 is new to it
    assert (refined, judged) == ([7, 3], [7, 3])
    whole = pipeline_of(Settings()).process(frame)
    assert analysis.tags == whole.tags
    assert analysis.selected == pending.selected


def test_a_small_tag_is_read_whole_before_its_tag() -> None:
    pipeline, detector = _coarse_pipeline()
    assert pipeline.coarse is not None
    before = detector.reads
    frame = _hd([(3, _square(900, 400, 30))])
    pending = pipeline.begin(frame)
    assert detector.reads == before + 1
    assert pending.selected.tag_id == 3
    assert pending.finish().selected == pending.selected
    assert pipeline.coarse.counters == {"reads": 1, "answered": 0, "slow": 0}
    # and the frame after: no near tag, no coarse read
    pipeline.process(frame)
    assert pipeline.coarse.counters["reads"] == 1


def test_a_look_alike_larger_than_the_tag_is_vetoed_on_full_resolution_pixels(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pipeline, detector = _coarse_pipeline()
    image = render_markers(1280, 720, [(5, _square(100, 100, 240)), (7, _square(700, 200, 150))])
    # a marker without paper around it (a printed pattern on a dark box), larger than tag 7
    image[40:400, 40:400][:, :, :3] = np.where(
        np.pad(np.ones((240, 240), bool), 60)[:, :, None], image[40:400, 40:400, :3], 40
    )
    frame = Frame(image, ENCODINGS["bgra8"], None, "test", None)
    judged: list[tuple[int, tuple[int, ...]]] = []
    check = Verifier.check

    def seen(self: Verifier, gray: npt.NDArray[np.uint8], detection: Detection) -> str | None:
        judged.append((detection.tag_id, gray.shape))
        return check(self, gray, detection)

    monkeypatch.setattr(Verifier, "check", seen)
    before = detector.reads
    pending = pipeline.begin(frame)
    assert detector.reads == before  # answered from the coarse read
    assert pending.selected.tag_id == 7
    assert judged[0] == (5, (720, 1280))  # the look-alike first, on the whole frame's pixels
    analysis = pending.finish()
    assert [t.tag_id for t in analysis.tags] == [7]
    assert pipeline.vetoed["quiet_zone"] >= 1


@pytest.mark.parametrize(
    "settings",
    [
        Settings(),
        Settings.from_flat(coarse_first_read=True, policy="center"),
        Settings.from_flat(
            coarse_first_read=True, metric="distance", camera_info_key="cam/info", tag_size_m=0.2
        ),
        Settings.from_flat(coarse_first_read=True, confirm_frames=2),
        Settings.from_flat(coarse_first_read=True, refine_corners=False),
    ],
    ids=["off", "center", "distance", "confirm", "unrefined"],
)
def test_no_coarse_read_where_it_may_not_give_the_whole_read_s_answer(
    settings: Settings,
) -> None:
    pipeline, detector = _coarse_pipeline(settings)
    assert pipeline.coarse is None
    before = detector.reads
    pipeline.begin(_hd(NEAR))
    assert detector.reads == before + 1
