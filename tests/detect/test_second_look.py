"""The second look: small markers OpenCV's default read misses, and where it is not taken."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from tests.helpers import pipeline_of
from zenoh_perception.detect import second_look
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.second_look import (
    LATER,
    MAX_CANDIDATES,
    MAX_SIDE_PX,
    MID_LINES,
    MID_PASS,
    NOW,
    PERIOD,
    Pass,
    SecondLook,
)
from zenoh_perception.detect.types import Detection
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import ENCODINGS, Frame
from zenoh_perception_bench.scene.lookalikes import lookalike_frame

Gray = npt.NDArray[np.uint8]
DICTIONARY = "DICT_4X4_50"


def _marker(tag_id: int, side_px: int) -> Gray:
    """A printed marker with a quiet zone of two cells, its black square ``side_px`` wide."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    printed = cv2.copyMakeBorder(
        cv2.aruco.generateImageMarker(dictionary, tag_id, 60),
        *(20,) * 4,
        cv2.BORDER_CONSTANT,
        value=255,
    )
    total = round(side_px * 100 / 60)
    return np.asarray(cv2.resize(printed, (total, total), interpolation=cv2.INTER_AREA), np.uint8)


def _frame(
    *markers: tuple[int, int, int, int], shape: tuple[int, int] = (480, 640), blur: float = 0.0
) -> Gray:
    """A grey frame with markers (id, side px, x, y of the print's top-left), each print
    blurred by a Gaussian of ``blur`` px when given."""
    noise = np.random.default_rng(0).normal(0.0, 3.0, shape)
    frame = np.clip(120.0 + noise, 0, 255).astype(np.uint8)
    for tag_id, side_px, x, y in markers:
        print_ = _marker(tag_id, side_px)
        if blur:
            print_ = np.asarray(cv2.GaussianBlur(print_, (0, 0), blur), np.uint8)
        frame[y : y + print_.shape[0], x : x + print_.shape[1]] = print_
    return frame


# A 10 px marker: OpenCV's default read finds nothing, the 2x read with one window finds it.
SMALL = (7, 10, 300, 200)


def _ids(found: list[Detection]) -> list[int]:
    return sorted(d.tag_id for d in found)


def test_the_look_finds_a_marker_too_small_for_the_default_read() -> None:
    frame = _frame(SMALL)
    assert OpenCvDetector(DICTIONARY).detect(frame) == []
    found = OpenCvDetector(DICTIONARY, second_look=SecondLook((DICTIONARY,))).detect(frame)
    assert _ids(found) == [7]
    # in the frame's pixels: the centre of the print (17 px wide, the marker in its middle)
    centre = found[0].corners.mean(axis=0)
    assert np.allclose(centre, (300 + 8, 200 + 8), atol=1.0)


def test_beside_a_large_marker_the_look_comes_after_the_frame_s_tag() -> None:
    look = SecondLook((DICTIONARY,))
    detector = OpenCvDetector(DICTIONARY, second_look=look)
    frame = _frame(SMALL, (3, 60, 40, 40))
    assert _ids(detector.detect(frame)) == [3]  # the read returns before the look
    assert look.counters["looks"] == 0
    assert _ids(detector.look_again()) == [7]  # only what the look adds
    assert detector.look_again() == []  # once a frame


def test_the_service_s_tag_does_not_wait_for_a_look_that_cannot_change_it() -> None:
    pipeline = pipeline_of(Settings())
    pending = pipeline.begin(_bgra(_frame(SMALL, (3, 60, 40, 40))))
    assert pending.selected.tag_id == 3
    detector = pipeline.detector
    assert isinstance(detector, OpenCvDetector)
    assert isinstance(detector.second_look, SecondLook)
    assert detector.second_look.counters["looks"] == 0  # not taken before the tag
    analysis = pending.finish()
    assert sorted(t.tag_id for t in analysis.tags) == [3, 7]
    assert analysis.selected.tag_id == 3


HD720 = (720, 1280)
# A far tag in an HD720 frame: 14 px and soft. OpenCV's default read rejects its quad (a cell
# read wrong); read again enlarged, with the bit corrected, it is id 7.
FAR = (7, 14, 600, 300)


def test_larger_frames_are_looked_at_also_on_every_frame_where_nothing_was_found() -> None:
    for shape, again in ((HD720, NOW), ((720, 960), NOW), ((MID_LINES, MAX_SIDE_PX), None)):
        look = SecondLook((DICTIONARY,))
        assert look.due(shape, []) == NOW  # the first frame
        assert look.due(shape, []) == again  # nothing found, as before


def test_a_far_tag_in_a_large_frame_is_read_from_the_candidate_opencv_rejected() -> None:
    frame = _frame(FAR, shape=HD720, blur=1.0)
    assert OpenCvDetector(DICTIONARY).detect(frame) == []
    look = SecondLook((DICTIONARY,))
    found = OpenCvDetector(DICTIONARY, second_look=look).detect(frame)
    assert _ids(found) == [7]
    assert look.counters["candidates"] == 1
    # in the frame's pixels: the centre of the print (23 px wide, the marker in its middle)
    assert np.allclose(found[0].corners.mean(axis=0), (600 + 11, 300 + 11), atol=1.0)
    tagged = _bgra(frame)
    assert pipeline_of(Settings()).process(tagged).selected.tag_id == 7
    assert pipeline_of(Settings.from_flat(second_look=False)).process(tagged).selected.tag_id == -1


def test_a_corrected_read_is_added_only_when_its_cells_read_its_id_clearly(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    frame = _frame(FAR, shape=HD720, blur=1.0)
    monkeypatch.setattr(second_look, "CORRECTED_MARGIN_BITS", 8.0)  # more than any read has
    look = SecondLook((DICTIONARY,))
    assert OpenCvDetector(DICTIONARY, second_look=look).detect(frame) == []
    assert look.counters == {"looks": 1, "candidates": 1, "added": 0}


def test_a_small_frame_s_look_leaves_its_candidates() -> None:
    """Read with their bits corrected, small frames' candidates gave look-alikes the veto
    keeps on the corpus's small negatives; the whole read at 2x reads them there."""
    frame = _frame(SMALL)
    frame[100:116, 100:116] = 20  # a dark square OpenCV's default read rejects
    detector = OpenCvDetector(DICTIONARY)
    found = detector.detect(frame)
    look = SecondLook((DICTIONARY,))
    assert _ids(look.look(frame, found, rejected=detector._rejected)) == [7]
    assert look.counters == {"looks": 1, "candidates": 0, "added": 1}


def test_a_corrected_read_is_added_only_when_seen_nearly_face_on(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A far marker squeezed to 8 x 20 px (as if turned about 65° away): OpenCV's default read
    rejects it, read again with a bit corrected it is id 7, but too foreshortened to trust."""
    frame = _frame(shape=HD720)
    print_ = cv2.resize(_marker(7, 60), (13, 33), interpolation=cv2.INTER_AREA)
    frame[300:333, 600:613] = cv2.GaussianBlur(print_, (0, 0), 1.0)
    assert OpenCvDetector(DICTIONARY).detect(frame) == []
    look = SecondLook((DICTIONARY,))
    assert OpenCvDetector(DICTIONARY, second_look=look).detect(frame) == []
    assert look.counters["candidates"] >= 1
    monkeypatch.setattr(second_look, "CORRECTED_MIN_SIDE_RATIO", 0.0)
    assert _ids(
        OpenCvDetector(DICTIONARY, second_look=SecondLook((DICTIONARY,))).detect(frame)
    ) == [7]


def test_only_the_candidates_most_like_a_marker_on_paper_are_read_again() -> None:
    """Dark squares straight on the grey ground leave OpenCV candidates too; the tag's print,
    light around its dark square, is read first however many there are."""
    frame = _frame(FAR, shape=HD720, blur=1.0)
    for index in range(3 * MAX_CANDIDATES):
        x, y = 40 + 50 * (index % 24), 80 + 400 * (index // 24) + 40 * (index % 2)
        frame[y : y + 16, x : x + 16] = 20
    look = SecondLook((DICTIONARY,))
    assert _ids(OpenCvDetector(DICTIONARY, second_look=look).detect(frame)) == [7]
    assert look.counters["candidates"] == MAX_CANDIDATES


def _square(tag_id: int, side: float) -> Detection:
    return Detection(tag_id, np.asarray([[0, 0], [side, 0], [side, side], [0, side]], np.float32))


def test_looks_on_the_first_frame_every_period_and_when_fewer_are_found() -> None:
    look = SecondLook((DICTIONARY,))
    small, large = _square(1, 10), _square(2, 40)
    shape = (480, 640)
    looked = [look.due(shape, [small]) for _ in range(PERIOD + 1)]
    assert looked == [NOW] + [None] * (PERIOD - 1) + [NOW]
    assert look.due(shape, []) == NOW  # fewer than before
    assert look.due(shape, []) is None  # none again: not fewer
    assert look.due(shape, [large, small]) is None
    assert look.due(shape, [large]) == LATER  # fewer, but a larger marker is there


def test_after_a_look_that_added_a_marker_the_next_frame_is_looked_at() -> None:
    frame = _frame(SMALL)
    look = SecondLook((DICTIONARY,))
    detector = OpenCvDetector(DICTIONARY, second_look=look)
    for _ in range(PERIOD):  # the first frame's look finds it, and each look after it
        assert _ids(detector.detect(frame)) == [7]
    assert look.counters == {"looks": PERIOD, "candidates": 0, "added": PERIOD}
    blank = _frame()
    assert detector.detect(blank) == []  # looked at: the look before added a marker
    assert detector.detect(blank) == []  # that look added none: not looked at
    assert look.counters["looks"] == PERIOD + 1


def test_the_look_adds_nothing_the_default_read_found() -> None:
    frame = _frame((7, 24, 300, 200))
    look = SecondLook((DICTIONARY,))
    found = OpenCvDetector(DICTIONARY).detect(frame)
    assert _ids(found) == [7]
    assert look.look(frame, found) == found
    assert look.counters == {"looks": 1, "candidates": 0, "added": 0}


def test_the_detectors_take_it_by_default_and_leave_it_when_told() -> None:
    frame = _frame(SMALL)
    for name in ("opencv", "tracking"):
        assert _ids(make_detector(name, DICTIONARY).detect(frame)) == [7]
        assert make_detector(name, DICTIONARY, second_look=False).detect(frame) == []


def _bgra(gray: Gray) -> Frame:
    bgra = np.asarray(cv2.cvtColor(gray, cv2.COLOR_GRAY2BGRA), np.uint8)
    return Frame(bgra, ENCODINGS["bgra8"], None, "t", None)


def test_the_service_reports_a_small_tag_the_default_read_misses() -> None:
    frame = _bgra(_frame(SMALL))
    assert pipeline_of(Settings()).process(frame).selected.tag_id == 7
    assert pipeline_of(Settings.from_flat(second_look=False)).process(frame).selected.tag_id == -1


def test_the_veto_judges_what_the_look_adds() -> None:
    """Handling pictograms on cardboard: the look reads ids on them that the default read does
    not, on a ground like paper, and the veto removes every one (their strokes)."""
    rng = np.random.default_rng(5)
    added = 0
    for _ in range(12):
        frame = lookalike_frame("pictograms", DICTIONARY, rng)
        gray = np.asarray(cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY), np.uint8)
        default = OpenCvDetector(DICTIONARY).detect(gray)
        added += len(SecondLook((DICTIONARY,)).look(gray, list(default))) - len(default)
        tagged = Frame(frame, ENCODINGS["bgra8"], None, "t", None)
        with_look = pipeline_of(Settings()).process(tagged).tags
        without = pipeline_of(Settings.from_flat(second_look=False)).process(tagged).tags
        assert [t.tag_id for t in with_look] == [t.tag_id for t in without]
    assert added > 0  # the look did add look-alikes here


def test_the_look_adds_nothing_on_a_dark_surround() -> None:
    """Key-caps, lettering and floor tiles: read at 2x, their dark squares decode as ids on a
    surround darker than a printed marker's margin; the look adds none of them."""
    rng = np.random.default_rng(5)
    for kind in ("keys", "text", "tiles"):
        for _ in range(6):
            frame = lookalike_frame(kind, DICTIONARY, rng)
            gray = np.asarray(cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY), np.uint8)
            default = OpenCvDetector(DICTIONARY).detect(gray)
            assert SecondLook((DICTIONARY,)).look(gray, list(default)) == default


def _board(square_px: float, blur: float, shape: tuple[int, int] = (180, 320)) -> Gray:
    """A 5x5 ChArUco board of DICT_4X4_50 (12 markers, ids 0-11, each three quarters of its
    square) with squares of ``square_px``, on a dark ground in a frame of ``shape``,
    blurred by a Gaussian of ``blur`` px: a phone's low-resolution video of a board."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    board = cv2.aruco.CharucoBoard((5, 5), 0.01, 0.0075, dictionary)
    side = round(5 * square_px)
    image = cv2.resize(board.generateImage((500, 500)), (side, side), interpolation=cv2.INTER_AREA)
    noise = np.random.default_rng(0).normal(0.0, 3.0, shape)
    frame = np.clip(60.0 + noise, 0, 255).astype(np.uint8)
    y, x = (shape[0] - side) // 2, (shape[1] - side) // 2
    frame[y : y + side, x : x + side] = image
    return np.asarray(cv2.GaussianBlur(frame, (0, 0), blur), np.uint8)


def test_a_low_resolution_frame_s_marker_only_its_pass_reads(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # 320x180, markers of 15 px (2.5 px a cell), soft: the default read and the 2x read with
    # one 13 px window miss id 7, the low-resolution pass's windows read it
    frame = _board(20.0, 0.9)
    default = OpenCvDetector(DICTIONARY).detect(frame)
    assert 7 not in _ids(default)
    assert 7 in _ids(SecondLook((DICTIONARY,)).look(frame, list(default)))
    monkeypatch.setattr(second_look, "LOW_RES_PASS", MID_PASS)  # the one window instead
    assert 7 not in _ids(SecondLook((DICTIONARY,)).look(frame, list(default)))


def test_a_low_resolution_frame_is_looked_at_when_fewer_are_found_than_lately() -> None:
    markers = [_square(tag_id, 14) for tag_id in range(5)]
    for shape, low_res in (((180, 320), True), ((480, 640), False), (HD720, False)):
        look = SecondLook((DICTIONARY,))
        assert look.due(shape, markers) == NOW  # the first frame
        assert look.due(shape, markers) is None  # as many as ever: the look cannot help
        assert look.due(shape, markers[:3]) == NOW  # fewer than on the frame before
        # as many as the frame before, fewer than lately: a low-resolution frame's small
        # markers come and go, so only there is it looked at again
        assert look.due(shape, markers[:3]) == (NOW if low_res else None)
        assert look.due(shape, markers) is None  # as many as ever again
    look = SecondLook((DICTIONARY,))
    look.due((180, 320), markers)
    # fewer than lately, but a marker over 32 px: its tag goes out before the look
    assert look.due((180, 320), [_square(9, 40), *markers[:3]]) == LATER


def _misprinted(tag_id: int, side_px: int) -> Gray:
    """:func:`_marker` with one inner cell (row 2, column 3) printed the wrong way round."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    marker = cv2.aruco.generateImageMarker(dictionary, tag_id, 60)  # cells of 10 px
    marker[30:40, 40:50] = 255 - marker[30:40, 40:50]
    printed = cv2.copyMakeBorder(marker, *(20,) * 4, cv2.BORDER_CONSTANT, value=255)
    total = round(side_px * 100 / 60)
    return np.asarray(cv2.resize(printed, (total, total), interpolation=cv2.INTER_AREA), np.uint8)


def _with_misprint(shape: tuple[int, int]) -> Gray:
    """A frame of ``shape`` with marker 7 of 16 px (2.7 px a cell), a cell misread, soft."""
    frame = _frame(shape=shape)
    print_ = _misprinted(7, 16)
    frame[60 : 60 + print_.shape[0], 140 : 140 + print_.shape[1]] = print_
    return np.asarray(cv2.GaussianBlur(frame, (0, 0), 0.8), np.uint8)


def test_a_low_resolution_frame_s_marker_only_the_chosen_pass_reads(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """320x180 with a 16 px marker that reads one cell wrong: the default read corrects no bit
    of a 4x4 code, the passes before (one 13 px window, windows 9 and 17) neither; the
    low-resolution pass corrects it, and the service reports it."""
    frame = _with_misprint((180, 320))
    default = OpenCvDetector(DICTIONARY).detect(frame)
    assert default == []
    assert _ids(SecondLook((DICTIONARY,)).look(frame, [])) == [7]
    tagged = _bgra(frame)
    assert pipeline_of(Settings()).process(tagged).selected.tag_id == 7
    for before in (MID_PASS, Pass((9, 17, 8))):
        monkeypatch.setattr(second_look, "LOW_RES_PASS", before)
        assert SecondLook((DICTIONARY,)).look(frame, []) == []


def test_frames_of_more_lines_than_a_pass_can_help_are_not_read_whole(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """960x720: on the corpus no pass read a marker the default missed on frames of over 480
    lines, so such a frame is looked at only at the candidates OpenCV rejected (none here)."""
    frame = _frame(SMALL, shape=(720, 960))
    look = SecondLook((DICTIONARY,))
    assert look.look(frame, [], rejected=()) == []
    assert look.counters == {"looks": 1, "candidates": 0, "added": 0}
    monkeypatch.setattr(second_look, "MID_LINES", 720)  # read whole, the 10 px marker is read
    assert _ids(SecondLook((DICTIONARY,)).look(frame, [], rejected=())) == [7]
