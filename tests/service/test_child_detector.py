"""service/child_detector.py: a detector in a child process, each read bounded by a deadline."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from tools.rig import marker_frame
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.errors import FrameAbandonedError, ProcessingError
from zenoh_perception.pipeline import TagFinder
from zenoh_perception.service.child_detector import IsolatedDetector
from zenoh_perception.wire.frames import ENCODINGS, Frame, to_gray

#: A pixel value that makes the test detectors misbehave; any other image reads normally.
_STALL, _CRASH, _FAIL = 1, 2, 3


class _Misbehaving(Detector):
    """OpenCV's detector, except on an image whose first pixel says to stall, crash or fail."""

    def __init__(self) -> None:
        self._opencv = make_detector("opencv", "DICT_4X4_50")

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        first = int(gray[0, 0])
        if first == _STALL:
            time.sleep(60.0)
        elif first == _CRASH:
            os.abort()  # what a segfault inside OpenCV does to the process
        elif first == _FAIL:
            msg = "a detector error on this frame"
            raise cv2.error(msg)
        return self._opencv.detect(gray)


def _misbehaving() -> _Misbehaving:
    return _Misbehaving()


class _AfterStall(_Misbehaving):
    """The detector of a spare child: says so in its detections' dictionary."""

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        return [replace(d, dictionary="after_stall") for d in super().detect(gray)]


def _dies_at_start() -> _Misbehaving:
    os._exit(3)


def _gray(tag_id: int = 3) -> npt.NDArray[np.uint8]:
    frame = marker_frame(640, 480, tag_id, side=120)
    bgra = np.frombuffer(frame.payload, np.uint8).reshape(480, 640, 4)
    return np.asarray(cv2.cvtColor(bgra, cv2.COLOR_BGRA2GRAY), np.uint8)


def _marked(value: int) -> npt.NDArray[np.uint8]:
    gray = _gray()
    gray[0, 0] = value
    return gray


@pytest.fixture
def stop() -> threading.Event:
    return threading.Event()


@pytest.fixture
def detector(stop: threading.Event) -> Iterator[IsolatedDetector]:
    with IsolatedDetector(_misbehaving, 0.3, stop=stop) as isolated:
        yield isolated


def _same(found: list[Detection], expected: list[Detection]) -> None:
    assert [d.tag_id for d in found] == [d.tag_id for d in expected]
    for a, b in zip(found, expected, strict=True):
        np.testing.assert_array_equal(a.corners, b.corners)


def test_finds_exactly_what_the_same_detector_finds_in_process() -> None:
    gray = _gray(5)
    expected = make_detector("opencv", "DICT_4X4_50").detect(gray)
    with IsolatedDetector(partial(make_detector, "opencv", "DICT_4X4_50"), 5.0) as isolated:
        found = isolated.detect(gray)
        assert isolated.detect(gray[:240, :320].copy()) == []  # a smaller frame, same segment
        _same(isolated.detect(gray), expected)
    _same(found, expected)
    assert [d.tag_id for d in found] == [5]


def test_the_spare_that_takes_over_from_a_killed_read_is_built_by_after_stall(
    stop: threading.Event,
) -> None:
    with IsolatedDetector(_misbehaving, 0.3, stop=stop, after_stall=_AfterStall) as isolated:
        assert [d.dictionary for d in isolated.detect(_gray(5))] == ["DICT_4X4_50"]
        with pytest.raises(FrameAbandonedError):
            isolated.detect(_marked(_STALL))
        assert [(d.tag_id, d.dictionary) for d in isolated.detect(_gray(5))] == [(5, "after_stall")]


def test_a_read_past_the_deadline_is_abandoned_and_the_next_frame_read(
    detector: IsolatedDetector,
) -> None:
    with pytest.raises(FrameAbandonedError) as caught:
        detector.detect(_marked(_STALL))
    assert caught.value.elapsed_ms >= 300.0
    assert detector.restarts == 1
    assert [d.tag_id for d in detector.detect(_gray())] == [3]


def test_a_crash_in_the_child_is_a_processing_error_and_the_child_restarts(
    detector: IsolatedDetector,
) -> None:
    with pytest.raises(ProcessingError, match="died") as caught:
        detector.detect(_marked(_CRASH))
    assert caught.value.stage == "detect"
    assert detector.restarts == 1
    assert [d.tag_id for d in detector.detect(_gray())] == [3]


def test_a_detector_error_is_a_processing_error_and_the_child_carries_on(
    detector: IsolatedDetector,
) -> None:
    with pytest.raises(ProcessingError, match="a detector error") as caught:
        detector.detect(_marked(_FAIL))
    assert caught.value.stage == "detect"
    assert detector.restarts == 0
    assert [d.tag_id for d in detector.detect(_gray())] == [3]


def test_a_child_that_dies_before_it_is_ready_is_a_processing_error() -> None:
    with IsolatedDetector(_dies_at_start, 5.0) as isolated:
        with pytest.raises(ProcessingError, match="exit code 3"):
            isolated.detect(_gray())
        assert isolated.restarts == 1


def test_stop_ends_a_stalled_read_at_once(stop: threading.Event) -> None:
    with IsolatedDetector(_misbehaving, 60.0, stop=stop) as isolated:
        isolated.detect(_gray())  # the child is up and its detector built
        timer = threading.Timer(0.2, stop.set)
        timer.start()
        try:
            with pytest.raises(FrameAbandonedError):
                isolated.detect(_marked(_STALL))
        finally:
            timer.join()


def test_close_kills_the_children_and_frees_the_shared_memory() -> None:
    isolated = IsolatedDetector(_misbehaving, 5.0)
    isolated.start()
    isolated.detect(_gray())
    children = [c.process for c in (isolated._active, isolated._spare) if c is not None]
    segment = isolated._segment
    assert segment is not None and len(children) == 2
    isolated.close()
    assert not any(child.is_alive() for child in children)
    assert not Path("/dev/shm", segment.name.lstrip("/")).exists()


def test_an_image_converted_into_the_gray_buffer_is_read_where_it_is() -> None:
    gray = _gray(5)
    expected = make_detector("opencv", "DICT_4X4_50").detect(gray)
    with IsolatedDetector(partial(make_detector, "opencv", "DICT_4X4_50"), 5.0) as isolated:
        buffer = isolated.gray_buffer(*gray.shape)
        buffer[...] = gray
        _same(isolated.detect(buffer), expected)
        _same(isolated.detect(gray.copy()), expected)  # any other image is copied in
        # a larger frame grows the segment while the past frame's array is still alive
        big = np.zeros((960, 1280), np.uint8)
        big[:480, :640] = gray
        large = isolated.gray_buffer(*big.shape)
        large[...] = big
        assert [d.tag_id for d in isolated.detect(large)] == [5]
        assert [d.tag_id for d in isolated.detect(buffer[:240, :320].copy())] == []
        del buffer, large


def test_the_finder_converts_into_the_detectors_gray_buffer() -> None:
    frame = marker_frame(640, 480, 5, side=120)
    bgra = np.frombuffer(frame.payload, np.uint8).reshape(480, 640, 4)
    decoded = Frame(bgra, ENCODINGS["bgra8"], None, "test", None)
    with IsolatedDetector(partial(make_detector, "opencv", "DICT_4X4_50"), 5.0) as isolated:
        finder = TagFinder(isolated)
        found, _ = finder.find(decoded)
        assert [d.tag_id for d in found] == [5]
        assert isolated._segment is not None
        shared = np.ndarray((480, 640), np.uint8, isolated._segment.buf)
        np.testing.assert_array_equal(shared, to_gray(decoded))
        del shared
