"""Periodic grids found on generated boards, painted over, and kept from OpenCV's detector;
markers beside a board and a ChArUco board's markers still found."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.grids import (
    _HOLD_READS,
    GridKeeper,
    grid_mask,
    keep_grids_away,
    on_painted,
)
from zenoh_perception.detect.opencv import OpenCvDetector, aruco_dictionary
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator
from zenoh_perception_bench.scene.boards import BOARD_KINDS, board_scene

W, H = 1280, 720


def _gray(image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)


def _candidates(gray: npt.NDArray[np.uint8]) -> int:
    """How many quads OpenCV's default detector considered (found and rejected)."""
    params = cv2.aruco.DetectorParameters()
    detector = cv2.aruco.ArucoDetector(aruco_dictionary("DICT_4X4_50"), params)
    corners, _ids, rejected = detector.detectMarkers(gray)
    return len(corners) + len(rejected)


@pytest.mark.parametrize("kind", BOARD_KINDS)
@pytest.mark.parametrize("square", [8, 12, 20])
def test_a_board_is_found_and_nothing_beside_it(kind: str, square: int) -> None:
    scene = board_scene(W, H, square, kind)
    mask = grid_mask(_gray(scene.image))
    assert mask is not None
    # a good part of the board is painted (all of it for straight boards) ...
    least = 0.8 if kind == "straight" else 0.05
    assert mask[scene.board].mean() > least
    # ... and nothing a tag's width away from it
    assert not mask[:, W // 2 + 60 :].any()


@pytest.mark.parametrize("kind", ["straight", "perspective"])
def test_painting_keeps_the_candidates_from_opencv(kind: str) -> None:
    gray = _gray(board_scene(W, H, 12, kind).image)
    painted, mask = keep_grids_away(gray)
    assert mask is not None and painted is not gray
    assert _candidates(painted) < _candidates(gray) / 4


def test_plain_scenes_and_a_lone_tag_are_left_whole() -> None:
    scenes = SceneGenerator(CameraModel.named("HD720"), seed=3, effects=Effects.clean())
    for _ in range(4):
        gray = _gray(scenes.random_scene(4, 0).image)
        image, mask = keep_grids_away(gray)
        assert image is gray and mask is None
    assert grid_mask(np.full((480, 640), 200, np.uint8)) is None


def test_frames_under_vga_are_left_whole() -> None:
    gray = _gray(board_scene(320, 240, 10, "straight").image)
    assert grid_mask(gray) is None


@pytest.mark.parametrize("kind", BOARD_KINDS)
def test_the_tags_beside_a_board_are_found_with_the_board_kept_away(kind: str) -> None:
    scene = board_scene(W, H, 10, kind, tags=(3, 7, 11))
    gray = _gray(scene.image)
    detector = OpenCvDetector("DICT_4X4_50")
    detector.grids.armed = True
    found = detector.detect(gray)
    assert sorted(d.tag_id for d in found) == [3, 7, 11]
    # the board was painted: the keeper stays armed for the next frame
    assert detector.grids.armed
    for detection in found:
        truth = dict(scene.markers)[detection.tag_id]
        assert np.abs(detection.corners - truth).max() < 2.0


@pytest.mark.parametrize("square", [16, 20, 24, 30, 40])
def test_a_charuco_boards_markers_are_all_still_found(square: int) -> None:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    board = cv2.aruco.CharucoBoard((10, 9), float(square), square * 0.75, dictionary)
    picture = board.generateImage((10 * square, 9 * square), marginSize=0)
    frame = np.full((H, W), 255, np.uint8)
    frame[40 : 40 + picture.shape[0], 40 : 40 + picture.shape[1]] = picture
    plain = OpenCvDetector("DICT_4X4_50")
    kept = OpenCvDetector("DICT_4X4_50")
    kept.grids.armed = True
    expected = sorted(d.tag_id for d in plain.detect(frame))
    assert len(expected) == 45
    assert sorted(d.tag_id for d in kept.detect(frame)) == expected


def test_the_keeper_arms_after_an_expensive_read_and_disarms_after_plain_frames() -> None:
    keeper = GridKeeper()
    plain = np.full((H, W), 128, np.uint8)
    assert keeper.prepare(plain) is plain
    keeper.record(0.005, W * H)
    assert not keeper.armed
    # a costly read without grids: one look on the next frame, no more
    keeper.record(0.5, W * H)
    assert keeper.armed
    assert keeper.prepare(plain) is plain
    keeper.record(0.005, W * H)
    assert not keeper.armed
    keeper.record(0.5, W * H)
    board = _gray(board_scene(W, H, 10, "straight").image)
    assert keeper.prepare(board) is not board
    keeper.record(0.005, W * H)
    assert keeper.armed  # a grid was found: it stays armed however quick the read was
    # a plain frame amid board frames keeps it armed: the next board is not read whole
    for _ in range(_HOLD_READS - 1):
        assert keeper.prepare(plain) is plain
        keeper.record(0.005, W * H)
        assert keeper.armed
    assert keeper.prepare(board) is not board
    keeper.record(0.005, W * H)
    for _ in range(_HOLD_READS):
        assert keeper.armed
        keeper.prepare(plain)
        keeper.record(0.005, W * H)
    assert not keeper.armed


def test_a_read_stretched_by_a_busy_machine_does_not_arm_the_keeper(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a read that waits (its thread descheduled on a loaded machine) costs wall time, not CPU:
    # only what the read itself costs arms the keeper, so the same frames are painted at any load
    detector = OpenCvDetector("DICT_4X4_50")
    read = detector._detect

    def waiting_read(image: npt.NDArray[np.uint8], offset: tuple[int, int]) -> list[object]:
        threading.Event().wait(0.1)  # far past the budget of a VGA frame (15 ms), idle
        return read(image, offset)  # type: ignore[return-value]

    monkeypatch.setattr(detector, "_detect", waiting_read)
    detector.detect(np.full((480, 640), 128, np.uint8))
    assert not detector.grids.armed


def test_a_wary_keeper_looks_on_its_first_read_only_unless_grids_are_there() -> None:
    plain = np.full((H, W), 128, np.uint8)
    keeper = GridKeeper(armed=True)
    assert keeper.armed
    keeper.prepare(plain)
    keeper.record(0.005, W * H)
    assert not keeper.armed


def test_a_marker_on_painted_pixels_is_not_kept() -> None:
    mask = np.zeros((100, 100), bool)
    mask[40:60, 40:60] = True
    quad = np.array([[10, 10], [30, 10], [30, 30], [10, 30]], np.float32)
    assert not on_painted(quad, mask)
    assert on_painted(quad + 40, mask)


@pytest.mark.parametrize("name", ["opencv", "tracking"])
def test_a_wary_detector_keeps_a_board_away_from_its_first_read(name: str) -> None:
    # a detector that replaces one whose read stalled: the board that stalled it is painted
    # on the first frame, not read whole again (a read past the deadline each time)
    scene = board_scene(W, H, 10, "straight", tags=(3, 7))
    gray = _gray(scene.image)
    plain, wary = make_detector(name, "DICT_4X4_50"), make_detector(name, "DICT_4X4_50", wary=True)
    assert sorted(d.tag_id for d in wary.detect(gray)) == [3, 7]
    assert sorted(d.tag_id for d in plain.detect(gray)) == [3, 7]
    assert _keeper(wary)._mask is not None
    assert _keeper(plain)._mask is None


def _keeper(detector: object) -> GridKeeper:
    opencv = detector if isinstance(detector, OpenCvDetector) else detector._opencv  # type: ignore[attr-defined]
    keeper: GridKeeper = opencv.grids
    return keeper
