"""The passes study: each setting's read in the frame's pixels, and the veto's table per cell."""

from __future__ import annotations

import cv2
import numpy as np

from tools.passes import (
    CELL_BINS,
    SETTINGS,
    STATES,
    Setting,
    _cell_table,
    read,
    side_band,
    size_class,
    state,
)
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import measure

DICTIONARY = "DICT_4X4_50"


def _frame() -> np.ndarray:
    """A 320x240 grey frame with marker 5 (40 px, its print at (100, 80)) on white paper."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    printed = cv2.copyMakeBorder(
        cv2.aruco.generateImageMarker(dictionary, 5, 40), *(10,) * 4, cv2.BORDER_CONSTANT, value=255
    )
    frame = np.full((240, 320), 120, np.uint8)
    frame[80:140, 100:160] = printed
    return frame


def test_every_setting_s_corners_are_in_the_frame_s_pixels() -> None:
    frame = _frame()
    for setting in (s for s in SETTINGS if s.scale >= 1):
        found = read(setting, setting.detector(DICTIONARY), frame, DICTIONARY)
        assert [d.tag_id for d in found] == [5], setting.name
        # the black square spans pixels 110-149: its corners' centre is at 129.5, 109.5
        assert np.allclose(found[0].corners.mean(axis=0), (129.5, 109.5), atol=0.6), setting.name


def test_the_cell_table_bins_true_markers_by_pixels_a_cell() -> None:
    frame = _frame()
    default = Setting("default")
    marker = read(default, default.detector(DICTIONARY), frame, DICTIONARY)[0]
    measures = measure(frame, marker, DICTIONARY)
    assert measures.px_per_cell >= 6.0  # 40 px over 6 cells
    table = _cell_table([("default", measures.px_per_cell, measures)])
    assert list(table) == [f">= {CELL_BINS[-2]:g}"]
    assert table[f">= {CELL_BINS[-2]:g}"]["true"] == 1
    assert table[f">= {CELL_BINS[-2]:g}"]["vetoed"] == {}


def _square(side: float) -> Detection:
    return Detection(1, np.asarray([[0, 0], [side, 0], [side, side], [0, side]], np.float32))


def test_frames_are_banded_by_their_lines_and_markers_by_their_side() -> None:
    # a portrait phone video has as many lines as the same video landscape
    assert size_class((180, 320)) == size_class((320, 180)) == "<= 240 lines"
    assert size_class((480, 848)) == size_class((850, 478)) == "241-480 lines"
    assert size_class((720, 1280)) == "> 480 lines"
    assert [side_band(s) for s in (10, 16, 30, 100)] == ["0-16", "16-24", "24-32", ">= 64"]


def test_a_frame_s_state_is_what_the_default_read_found_there() -> None:
    assert state([]) == STATES[0]
    assert state([_square(60), _square(20)]) == STATES[1]
    assert state([_square(60), _square(40)]) == STATES[2]
