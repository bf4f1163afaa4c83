"""Confirmation on a stream: a marker is reported once seen on N frames in a row about in
place; a one-frame look-alike never is; it only drops detections."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import pipeline_of
from zenoh_perception.detect.confirm import Confirmer
from zenoh_perception.detect.types import Detection
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import ENCODINGS, Frame
from zenoh_perception_bench.scene import render_markers

SHAPE = (480, 640)


def _tag(tag_id: int, x0: float, y0: float = 100.0, side: float = 60.0) -> Detection:
    corners = [[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]]
    return Detection(tag_id, np.array(corners, np.float32), "DICT_4X4_50")


def test_a_marker_is_reported_from_its_nth_frame_in_a_row() -> None:
    confirmer = Confirmer(3)
    moving = [_tag(7, 100.0 + 50 * k) for k in range(5)]  # under a side a frame: followed
    answers = [confirmer.confirm(SHAPE, [tag]) for tag in moving]
    assert [held for _, held in answers] == [1, 1, 0, 0, 0]
    assert [kept for kept, _ in answers][2:] == [[moving[2]], [moving[3]], [moving[4]]]


def test_a_one_frame_look_alike_is_never_reported() -> None:
    confirmer = Confirmer(2)
    assert confirmer.confirm(SHAPE, [_tag(17, 300)]) == ([], 1)
    assert confirmer.confirm(SHAPE, []) == ([], 0)
    assert confirmer.confirm(SHAPE, [_tag(17, 300)]) == ([], 1)  # a gap starts it afresh


@pytest.mark.parametrize(
    "then",
    [
        _tag(8, 100),  # another id
        _tag(7, 250),  # farther than two sides from where it was
        _tag(7, 100, side=100.0),  # more than half as large again
        Detection(7, _tag(7, 100).corners, "DICT_4X4_100"),  # another dictionary
    ],
)
def test_only_the_same_marker_about_in_place_counts(then: Detection) -> None:
    confirmer = Confirmer(2)
    confirmer.confirm(SHAPE, [_tag(7, 100)])
    assert confirmer.confirm(SHAPE, [then]) == ([], 1)


def test_a_frame_of_another_size_starts_afresh() -> None:
    confirmer = Confirmer(2)
    confirmer.confirm(SHAPE, [_tag(7, 100)])
    assert confirmer.confirm((720, 1280), [_tag(7, 100)]) == ([], 1)


def test_one_frame_confirms_at_once() -> None:
    tags = [_tag(1, 10), _tag(2, 300)]
    assert Confirmer(1).confirm(SHAPE, tags) == (tags, 0)
    with pytest.raises(ValueError, match="at least 1"):
        Confirmer(0)


def test_the_pipeline_holds_a_new_tag_and_counts_it() -> None:
    quad = np.array([[200, 150], [300, 150], [300, 250], [200, 250]], np.float64)
    image = render_markers(640, 480, [(7, quad)])
    frame = Frame(image, ENCODINGS["bgra8"], None, "test", None)
    pipeline = pipeline_of(Settings.from_flat(confirm_frames=2))
    assert pipeline.process(frame).tags == ()
    assert pipeline.vetoed["unconfirmed"] == 1
    assert [t.tag_id for t in pipeline.process(frame).tags] == [7]
    assert [t.tag_id for t in pipeline_of(Settings()).process(frame).tags] == [7]
