"""service/guard.py: detection in the calling thread, a stalled read abandoned by ``check``
and the frames after it read in a child process for a while."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from dataclasses import replace

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from tests.helpers import wait_until
from tools.rig import marker_frame
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.errors import FrameAbandonedError
from zenoh_perception.service.child_detector import IsolatedDetector
from zenoh_perception.service.guard import LOW_PRIORITY, GuardedDetector, StaleDetection

#: A first pixel of this value stalls the test detector until RELEASE is set (in this process;
#: in the child, where nobody sets it, until the child is killed).
_STALL = 1
RELEASE = threading.Event()
#: Detectors the factory built in this process (the child builds its own).
BUILT: list[_Stalling] = []


class _Stalling(Detector):
    """OpenCV's detector, except on an image whose first pixel is _STALL."""

    def __init__(self) -> None:
        self._opencv = make_detector("opencv", "DICT_4X4_50")

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        if int(gray[0, 0]) == _STALL:
            RELEASE.wait(60.0)
        return self._opencv.detect(gray)


def _stalling() -> _Stalling:
    detector = _Stalling()
    BUILT.append(detector)
    return detector


class _AfterStall(_Stalling):
    """The detector built after a stall: says so in its detections' dictionary."""

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        return [replace(d, dictionary="after_stall") for d in super().detect(gray)]


def _after_stall() -> _AfterStall:
    detector = _AfterStall()
    BUILT.append(detector)
    return detector


def _gray(tag_id: int, *, stall: bool = False) -> npt.NDArray[np.uint8]:
    frame = marker_frame(640, 480, tag_id, side=120)
    bgra = np.frombuffer(frame.payload, np.uint8).reshape(480, 640, 4)
    gray = np.asarray(cv2.cvtColor(bgra, cv2.COLOR_BGRA2GRAY), np.uint8)
    if stall:
        gray[0, 0] = _STALL
    return gray


@pytest.fixture
def guard() -> Iterator[GuardedDetector]:
    RELEASE.clear()
    BUILT.clear()
    guarded = GuardedDetector(_stalling, 0.3, calm_s=0.5)
    guarded.start()
    try:
        yield guarded
    finally:
        RELEASE.set()  # no test leaves a thread stuck
        guarded.close()


class _Reader(threading.Thread):
    """A worker that reads one frame through ``guard`` and keeps what came of it."""

    def __init__(self, guard: GuardedDetector, gray: npt.NDArray[np.uint8]) -> None:
        super().__init__(daemon=True)
        self._guard, self._gray = guard, gray
        self.found: list[Detection] | None = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.found = self._guard.detect(self._gray)
        except BaseException as err:  # kept for the test to look at
            self.error = err


def _stall(guard: GuardedDetector) -> tuple[_Reader, float]:
    """A reader stuck on a stalling frame, and the time ``check`` abandoned it after."""
    reader = _Reader(guard, _gray(3, stall=True))
    reader.start()
    abandoned: list[float] = []

    def check() -> bool:
        elapsed = guard.check()
        if elapsed is not None:
            abandoned.append(elapsed)
        return bool(abandoned)

    wait_until(check, timeout=10.0, what="the stalled read abandoned")
    return reader, abandoned[0]


def test_frames_are_read_in_the_calling_thread_until_one_stalls(guard: GuardedDetector) -> None:
    gray = _gray(5)
    found = guard.detect(gray)
    assert [d.tag_id for d in found] == [5]
    np.testing.assert_array_equal(
        found[0].corners, make_detector("opencv", "DICT_4X4_50").detect(gray)[0].corners
    )
    assert not guard.in_child
    assert guard.gray_buffer(480, 640) is None  # any array: nothing to copy into a child
    assert guard.check() is None  # nothing in flight
    assert guard.abandon() is None


def test_check_leaves_a_read_alone_before_its_deadline(guard: GuardedDetector) -> None:
    reader = _Reader(guard, _gray(3, stall=True))
    reader.start()
    wait_until(lambda: guard.reading, timeout=5.0, what="the read in flight")
    assert guard.check() is None
    assert guard.poll_s() > 0.1  # the watchdog sleeps until the read's deadline
    RELEASE.set()
    reader.join(5.0)
    assert reader.error is None
    assert not guard.reading
    assert reader.found is not None and [d.tag_id for d in reader.found] == [3]


def test_a_stalled_read_is_abandoned_and_its_thread_ends_stale(guard: GuardedDetector) -> None:
    reader, elapsed_ms = _stall(guard)
    assert elapsed_ms >= 300.0
    assert guard.stuck == 1
    assert guard.in_child
    # the abandoned thread keeps running, at a low priority
    assert reader.native_id is not None
    assert os.getpriority(os.PRIO_PROCESS, reader.native_id) == LOW_PRIORITY
    # the next frame is read by the child, straight from its segment
    gray = _gray(7)
    buffer = guard.gray_buffer(480, 640)
    assert buffer is not None
    buffer[...] = gray
    assert [d.tag_id for d in guard.detect(buffer)] == [7]
    RELEASE.set()
    reader.join(5.0)
    assert not reader.is_alive()
    assert isinstance(reader.error, StaleDetection)
    assert reader.found is None  # its results are dropped
    assert guard.stuck == 0


def test_a_stall_in_the_child_is_killed_at_the_deadline(guard: GuardedDetector) -> None:
    reader, _ = _stall(guard)
    started = time.monotonic()
    with pytest.raises(FrameAbandonedError):
        guard.detect(_gray(3, stall=True))  # the child's RELEASE is never set
    assert time.monotonic() - started < 5.0
    assert guard.stuck == 1  # no second thread stuck in this process
    RELEASE.set()
    reader.join(5.0)
    assert [d.tag_id for d in guard.detect(_gray(9))] == [9]


def test_frames_return_in_process_once_the_thread_ended_and_calm_passed(
    guard: GuardedDetector,
) -> None:
    reader, _ = _stall(guard)
    assert len(BUILT) == 2  # a fresh detector for the next in-process read
    RELEASE.set()
    reader.join(5.0)
    wait_until(lambda: not guard.in_child, timeout=5.0, what="in process again")
    RELEASE.clear()
    assert guard.gray_buffer(480, 640) is None
    assert [d.tag_id for d in guard.detect(_gray(11))] == [11]
    # read in process: a stall there is abandoned by check again
    reader, _ = _stall(guard)
    assert guard.stuck == 1


def test_the_detectors_after_a_stall_come_from_after_stall() -> None:
    # the service builds them wary of periodic grids: the frames that stalled a read come again
    RELEASE.clear()
    BUILT.clear()
    guarded = GuardedDetector(_stalling, 0.3, calm_s=0.5, after_stall=_after_stall)
    guarded.start()
    try:
        assert [d.dictionary for d in guarded.detect(_gray(5))] == ["DICT_4X4_50"]
        reader, _ = _stall(guarded)
        assert isinstance(BUILT[-1], _AfterStall)  # the next in-process read's
        # the child's detector
        assert [(d.tag_id, d.dictionary) for d in guarded.detect(_gray(7))] == [(7, "after_stall")]
        RELEASE.set()
        reader.join(5.0)
        wait_until(lambda: not guarded.in_child, timeout=5.0, what="in process again")
        assert [(d.tag_id, d.dictionary) for d in guarded.detect(_gray(9))] == [(9, "after_stall")]
    finally:
        RELEASE.set()
        guarded.close()


def test_abandon_gives_the_thread_of_the_read_in_flight(guard: GuardedDetector) -> None:
    reader = _Reader(guard, _gray(3, stall=True))
    reader.start()
    wait_until(lambda: guard.reading, timeout=5.0, what="the read in flight")
    assert guard.abandon() == reader.ident
    RELEASE.set()
    reader.join(5.0)
    assert isinstance(reader.error, StaleDetection)


def test_after_abandon_no_read_starts(guard: GuardedDetector) -> None:
    # on shutdown a worker may still be decoding a frame: it must not go on to read it
    assert guard.abandon() is None
    with pytest.raises(StaleDetection):
        guard.detect(_gray(5))
    assert not guard.reading


def _may_raise_priority() -> bool:
    """Whether this process may raise a thread's priority again (root, CAP_SYS_NICE)."""
    allowed: list[bool] = []

    def probe() -> None:
        native = threading.get_native_id()
        normal = os.getpriority(os.PRIO_PROCESS, native)
        os.setpriority(os.PRIO_PROCESS, native, LOW_PRIORITY)
        try:
            os.setpriority(os.PRIO_PROCESS, native, normal)
        except PermissionError:
            allowed.append(False)
        else:
            allowed.append(True)

    thread = threading.Thread(target=probe)
    thread.start()
    thread.join()
    return allowed == [True]


def test_abandon_gives_an_abandoned_thread_its_priority_back_where_permitted(
    guard: GuardedDetector,
) -> None:
    # a lowered thread still in OpenCV would hold the process's exit up on a busy machine
    reader, _ = _stall(guard)
    assert reader.native_id is not None
    assert os.getpriority(os.PRIO_PROCESS, reader.native_id) == LOW_PRIORITY
    guard.abandon()
    normal = os.getpriority(os.PRIO_PROCESS, 0)
    expected = normal if _may_raise_priority() else LOW_PRIORITY
    assert os.getpriority(os.PRIO_PROCESS, reader.native_id) == expected
    RELEASE.set()
    reader.join(5.0)
    assert isinstance(reader.error, StaleDetection)


def _opencv() -> Detector:
    return make_detector("opencv", "DICT_4X4_50")


def test_the_look_after_the_tag_is_read_in_process_under_the_guard() -> None:
    from tests.detect.test_second_look import SMALL, _frame

    guarded = GuardedDetector(_opencv, 0.3)
    guarded.start()
    try:
        frame = _frame(SMALL, (3, 60, 40, 40))  # a large marker: the small one's look waits
        assert [d.tag_id for d in guarded.detect(frame)] == [3]
        assert [d.tag_id for d in guarded.look_again()] == [7]
        assert guarded.look_again() == []
        assert not guarded.reading
        guarded.detect(frame)
        guarded.abandon()  # shutting down: no read starts, the look's neither
        with pytest.raises(StaleDetection):
            guarded.look_again()
    finally:
        guarded.close()


class _SlowLook(_Stalling):
    """A detector whose look after the frame's tag stalls until RELEASE."""

    def look_again(self) -> list[Detection]:
        RELEASE.wait(60.0)
        return []


def _slow_look() -> _SlowLook:
    return _SlowLook()


def test_a_stalled_look_after_the_tag_is_abandoned_as_an_answered_frame() -> None:
    RELEASE.clear()
    guarded = GuardedDetector(_slow_look, 0.3, calm_s=0.5)
    guarded.start()
    try:
        reader, _ = _stall(guarded)  # a read before the tag: the frame is not answered
        assert not guarded.abandoned_answered
        RELEASE.set()
        reader.join(5.0)
        wait_until(lambda: not guarded.in_child, timeout=10.0, what="in process again")
        RELEASE.clear()
        errors: list[BaseException] = []

        def look() -> None:
            try:
                guarded.look_again()
            except BaseException as err:  # kept for the test to look at
                errors.append(err)

        looker = threading.Thread(target=look, daemon=True)
        looker.start()
        wait_until(lambda: guarded.check() is not None, timeout=10.0, what="the look abandoned")
        assert guarded.abandoned_answered
        RELEASE.set()
        looker.join(5.0)
        assert [type(e) for e in errors] == [StaleDetection]
    finally:
        RELEASE.set()
        guarded.close()


def test_a_read_given_to_watched_is_under_the_deadline_as_detect_s_is(
    guard: GuardedDetector,
) -> None:
    # the coarse first read: in the calling thread, abandoned by check past the deadline
    assert guard.watched(lambda: 5) == 5
    done: list[object] = []

    def stalled() -> None:
        try:
            done.append(guard.watched(lambda: RELEASE.wait(60.0)))
        except BaseException as err:  # kept for the test to look at
            done.append(err)

    reader = threading.Thread(target=stalled, daemon=True)
    reader.start()
    wait_until(lambda: guard.check() is not None, timeout=10.0, what="the read abandoned")
    assert not guard.abandoned_answered  # before the frame's tag: the frame is rejected
    assert guard.in_child
    # while frames go to the child an in-process read could not be bounded: none is taken
    assert guard.watched(lambda: 5) is None
    RELEASE.set()
    reader.join(5.0)
    assert [type(d) for d in done] == [StaleDetection]


def test_a_detector_in_a_child_process_takes_no_read_in_the_caller_s() -> None:
    isolated = IsolatedDetector(_opencv, 0.3)
    assert isolated.watched(lambda: 5) is None
    assert make_detector("opencv", "DICT_4X4_50").watched(lambda: 5) == 5  # no deadline
