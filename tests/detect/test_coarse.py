"""The coarse first read: which frames get it, which markers it offers as the tag."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.detect import coarse as coarse_module
from zenoh_perception.detect.coarse import GATE_SIDE_PX, CoarseRead, same_answer
from zenoh_perception.detect.types import R
from zenoh_perception.tags.geometry import tag_center
from zenoh_perception.tags.selection import TagMessage
from zenoh_perception_bench.scene import render_markers

DICT = ("DICT_4X4_50",)


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _gray(markers: list[tuple[int, npt.NDArray[np.float64]]]) -> npt.NDArray[np.uint8]:
    image = render_markers(1280, 720, markers)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)


def _read(previous: float) -> CoarseRead:
    coarse = CoarseRead(DICT)
    coarse.remember(previous)
    return coarse


def test_only_a_frame_after_a_near_tag_is_read_coarsely() -> None:
    coarse = CoarseRead(DICT)
    assert not coarse.due()  # the stream's first frame
    coarse.remember(GATE_SIDE_PX - 1)
    assert not coarse.due()
    coarse.remember(GATE_SIDE_PX)
    assert coarse.due()
    coarse.remember(0.0)  # no tag
    assert not coarse.due()


def test_the_largest_marker_comes_back_at_full_resolution() -> None:
    square = _square(300.3, 200.6, 180)
    candidates = list(_read(120).candidates(_gray([(7, square), (3, _square(800, 300, 100))])))
    assert [c.tag_id for c in candidates] == [7, 3]
    # within a pixel of the drawn corners before the pipeline's edge fit
    centre = tag_center(candidates[0].corners)
    assert np.hypot(centre[0] - 390.3, centre[1] - 290.6) < 0.5
    assert np.abs(candidates[0].corners - square.astype(np.float32)).max() < 1.5


def test_a_marker_on_a_narrow_paper_comes_back_with_the_whole_read_s_corners() -> None:
    # the crop's sides cut the ground around the paper into a quad close to the marker, which
    # OpenCV groups with it: asked to keep 3 px from the crop's sides, it drops the group
    gray = _gray([(7, _square(500.3, 200.6, 120))])
    paper = np.zeros(gray.shape, bool)
    paper[168:353, 468:653] = True
    ground = np.where(paper, gray, 120).astype(np.uint8)
    gray = np.asarray(cv2.GaussianBlur(ground, (0, 0), 1.0), np.uint8)
    corners, ids, _ = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    ).detectMarkers(gray)
    assert ids is not None and ids.ravel().tolist() == [7]
    candidates = list(_read(120).candidates(gray))
    assert [c.tag_id for c in candidates] == [7]
    assert np.array_equal(candidates[0].corners, corners[0].reshape(4, 2))


def test_a_marker_the_whole_read_drops_at_the_frame_s_border_is_not_offered() -> None:
    # 2 px from the frame's left border: under OpenCV's 3 px, which the crop keeps on that side
    gray = _gray([(7, _square(2.0, 200.3, 140))])
    _, ids, _ = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    ).detectMarkers(gray)
    assert ids is None or len(ids) == 0
    assert list(_read(140).candidates(gray)) == []


def test_a_small_tag_is_not_offered_it_is_read_whole() -> None:
    assert list(_read(120).candidates(_gray([(7, _square(300, 200, 30))]))) == []


def test_two_markers_of_about_one_size_are_left_to_the_whole_read() -> None:
    gray = _gray([(7, _square(200, 200, 150)), (3, _square(700, 200, 146))])
    assert list(_read(150).candidates(gray)) == []


def _with_dark_squares(count: int) -> npt.NDArray[np.uint8]:
    """Tag 7 (120 px) and ``count`` plain dark squares of 240 px on paper: quads with no
    code."""
    gray = _gray([(7, _square(100, 100, 120))])
    for index in range(count):
        x = 350 + 300 * index
        gray[150:450, x : x + 300] = 255
        gray[180:420, x + 30 : x + 270] = 0
    return gray


def test_larger_quads_it_cannot_read_are_read_at_full_resolution_before_the_tag() -> None:
    # nothing there at full resolution either: the tag is offered
    assert [c.tag_id for c in _read(120).candidates(_with_dark_squares(2))] == [7]
    # more than it may read again: read the frame whole
    assert list(_read(120).candidates(_with_dark_squares(3))) == []


def test_a_tag_of_the_frame_before_it_missed_stops_it() -> None:
    gray = _gray([(7, _square(100, 100, 120))])
    coarse = CoarseRead(DICT)
    coarse.remember(120, [(7, 120.0**2), (3, 100.0**2)])  # 3 may have grown past 7
    assert list(coarse.candidates(gray)) == []
    coarse.remember(120, [(7, 120.0**2), (3, 60.0**2)])  # 3 was far smaller
    assert [c.tag_id for c in coarse.candidates(gray)] == [7]


def test_the_same_answer_allows_half_a_pixel() -> None:
    a = TagMessage(7, 100.0, 50.0, 0.8)
    assert same_answer(a, TagMessage(7, 100.3, 50.3, 0.801))
    assert not same_answer(a, TagMessage(7, 100.4, 50.4, 0.8))
    assert not same_answer(a, TagMessage(3, 100.0, 50.0, 0.8))
    assert not same_answer(a, TagMessage(7, 100.0, 50.0, 0.81))


def test_after_a_slow_read_the_stream_s_next_frames_are_read_whole(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(coarse_module, "SLOW_READ_S", -1.0)  # every read is slow
    monkeypatch.setattr(coarse_module, "REST_FRAMES", 3)
    coarse = _read(120)
    assert coarse.due()
    assert [c.tag_id for c in coarse.candidates(_gray([(7, _square(100, 100, 120))]))] == [7]
    assert coarse.counters["slow"] == 1
    assert [coarse.due() for _ in range(4)] == [False, False, False, True]


class _AbandonedError(Exception):
    """What a read abandoned at the frame deadline raises in its thread once it returns (the
    service's guard raises its own)."""


def _abandoned(read: Callable[[], R]) -> R | None:
    read()
    raise _AbandonedError


def _not_taken(read: Callable[[], R]) -> R | None:
    return None


def test_a_read_abandoned_at_the_deadline_rests_the_coarse_read_as_a_slow_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(coarse_module, "REST_FRAMES", 3)
    coarse = _read(120)
    assert coarse.due()
    with pytest.raises(_AbandonedError):
        list(coarse.candidates(_gray([(7, _square(100, 100, 120))]), _abandoned))
    # the next frame's due() learns of it: the thread left in the read writes nothing more
    assert [coarse.due() for _ in range(5)] == [False, False, False, True, True]
    assert coarse.counters == {"reads": 1, "answered": 0, "slow": 1}


def test_no_coarse_read_where_the_deadline_cannot_bound_it() -> None:
    # frames read in a child process: an in-process read would escape the deadline
    coarse = _read(120)
    assert list(coarse.candidates(_gray([(7, _square(100, 100, 120))]), _not_taken)) == []
    assert coarse.counters == {"reads": 0, "answered": 0, "slow": 0}
    assert coarse.due()  # nothing rests it
