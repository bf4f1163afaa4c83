"""Detection under a deadline at no per-frame cost: the detector runs in the calling thread, and
only a frame that stalls it moves detection to a child process for a while.

Handing every frame to a child process (:class:`~zenoh_perception.service.child_detector.
IsolatedDetector`) bounds every frame but costs each one two process wake-ups. Stalls are rare
(a checkerboard, a tiled floor), so :class:`GuardedDetector` reads frames in the calling thread
(the service's worker) and a watchdog thread calls :meth:`GuardedDetector.check`:

- A read still running after ``deadline_s`` is abandoned: ``check`` returns its time, the
  watchdog starts another worker, and the stuck thread, lowered to a low scheduling priority,
  finishes OpenCV's call on its own; it then raises :class:`StaleDetection` (its
  results are dropped, it touches nothing else) and ends. A fresh detector serves the next
  in-process read, so a detector's state between frames starts afresh, as after a restart.
  The detectors built after a stall (in process and in the child) come from ``after_stall``:
  the service's keep periodic grids away from their first read, since the frames that
  stalled a read tend to come again.
- While an abandoned read is still running, and for ``calm_s`` after the last abandoned frame,
  frames go to the child process instead, where a stalled frame is killed at the deadline: a
  board that stays in view never leaves more than one thread stuck in OpenCV.

The pipeline's other reads of a frame (the coarse first read, :meth:`GuardedDetector.watched`)
are watched the same way; while frames go to the child they are not taken.

No Zenoh, no logging.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.types import Detection, Detector, R
from zenoh_perception.errors import FrameAbandonedError
from zenoh_perception.service.child_detector import DetectorFactory, IsolatedDetector

#: After the last abandoned frame, seconds during which frames still go to the child.
CALM_S: Final = 5.0
#: Longest sleep of the watchdog while no read is in flight, seconds: a read that starts
#: meanwhile is looked at no later than this, then exactly at its deadline.
_IDLE_POLL_S: Final = 0.1
#: The nice value an abandoned thread is lowered to (Linux threads each have their own): a
#: tenth of a normal thread's share of a busy core. Not 19 (a seventieth): the kernel ends a
#: process only once each of its threads has run again, and on a loaded machine a thread at
#: nice 19 waits seconds for that, which held up the exit on SIGTERM.
LOW_PRIORITY: Final = 10


class StaleDetection(Exception):  # noqa: N818 - not an error: the thread was replaced
    """Raised in the thread whose read the watchdog abandoned, once OpenCV returns: another
    thread has taken over, so this one must end without using the results."""


@dataclass
class _Read:
    """One in-process read in flight."""

    started: float  # time.monotonic()
    thread: int  # threading.get_ident()
    native_id: int
    abandoned: bool = False
    #: a read after the frame's tag was published (:meth:`GuardedDetector.look_again`)
    answered: bool = False


class GuardedDetector(Detector):
    """A detector built by ``factory``, read in the calling thread and guarded by
    :meth:`check`; see the module documentation. One worker thread calls :meth:`detect` at a
    time (a new one only once the previous one's read was abandoned).

    Raises (from :meth:`detect`):
        StaleDetection: this thread's read was abandoned, or :meth:`abandon` was called; the
            thread must end.
        FrameAbandonedError, ProcessingError: from the child process, while it reads.
    """

    def __init__(
        self,
        factory: DetectorFactory,
        deadline_s: float,
        *,
        stop: threading.Event | None = None,
        calm_s: float = CALM_S,
        after_stall: DetectorFactory | None = None,
        opencv_threads: int = 0,
    ) -> None:
        self.deadline_s = deadline_s
        self.calm_s = calm_s
        self._factory = after_stall if after_stall is not None else factory
        self._local: Detector = factory()
        # the child serves frames only after a stall
        self.isolated = IsolatedDetector(
            self._factory, deadline_s, stop=stop, opencv_threads=opencv_threads
        )
        self._lock = threading.Lock()
        self._read: _Read | None = None
        self._stuck = 0  # abandoned reads still inside the detector
        self._lowered: list[_Read] = []  # those of them lowered to LOW_PRIORITY
        self._calm_at = 0.0  # monotonic time from which frames may be read in process again
        self._closing = False  # set by abandon(): no read starts any more
        #: the read :meth:`check` abandoned last came after its frame's tag was published
        self.abandoned_answered = False

    def start(self) -> None:
        """Start the child process and its spare, ready for the first stall."""
        self.isolated.start()

    def close(self) -> None:
        self.isolated.close()

    @property
    def in_child(self) -> bool:
        """Whether the next frame goes to the child process."""
        return self._stuck > 0 or time.monotonic() < self._calm_at

    @property
    def reading(self) -> bool:
        """Whether a read is in flight in this process (not abandoned)."""
        return self._read is not None

    @property
    def stuck(self) -> int:
        """Abandoned reads still running in this process."""
        return self._stuck

    def gray_buffer(self, height: int, width: int) -> npt.NDArray[np.uint8] | None:
        """Where the next frame's grey image goes: the child's segment while frames go to the
        child, else None (any array)."""
        return self.isolated.gray_buffer(height, width) if self.in_child else None

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        if self._closing:
            raise StaleDetection
        if self.in_child:
            try:
                return self.isolated.detect(gray)
            except FrameAbandonedError:
                self._calm_at = time.monotonic() + self.calm_s
                raise
        return self._in_process(self._local.detect, gray, answered=False)

    def look_again(self) -> list[Detection]:
        """What the in-process detector's second look adds to the frame it read last, where
        that look was left until after the frame's tag; read under the deadline as
        :meth:`detect` is. [] while frames go to the child: its look is not taken."""
        if self.in_child:
            return []
        return self._in_process(self._local.look_again, answered=True)

    def watched(self, read: Callable[[], R]) -> R | None:
        """``read()`` in the calling thread, under the deadline as :meth:`detect`'s read is (the
        coarse first read, before the frame's tag). None while frames go to the child: an
        in-process read could not be bounded there (the read is not taken)."""
        if self.in_child:
            return None
        return self._in_process(read, answered=False)

    def _in_process(self, read_once: Callable[..., R], *args: object, answered: bool) -> R:
        """``read_once(*args)`` in the calling thread, as the read in flight that :meth:`check`
        watches (``answered``: it comes after the frame's tag was published)."""
        read = _Read(
            time.monotonic(), threading.get_ident(), threading.get_native_id(), answered=answered
        )
        with self._lock:
            if self._closing:  # abandon() came between the caller's check and here
                raise StaleDetection
            self._read = read
        try:
            found = read_once(*args)
        finally:
            self._finish(read)
        return found

    def _finish(self, read: _Read) -> None:
        """End ``read``: raise :class:`StaleDetection` when it was abandoned meanwhile."""
        with self._lock:
            if read.abandoned:
                self._stuck -= 1
                if read in self._lowered:
                    self._lowered.remove(read)
                raise StaleDetection
            self._read = None

    def check(self) -> float | None:
        """Abandon the in-process read when it has run past the deadline: its time in ms (the
        caller starts another worker), else None."""
        now = time.monotonic()
        with self._lock:
            read = self._read
            if read is None or now - read.started < self.deadline_s:
                return None
            read.abandoned = True
            self.abandoned_answered = read.answered
            self._read = None
            self._stuck += 1
            self._calm_at = now + self.calm_s
            # under the lock: the thread cannot end meanwhile, its id is still its own
            if _set_priority(read.native_id, LOW_PRIORITY):
                self._lowered.append(read)
        # The abandoned detector stays with its thread; a detector keeping state between
        # frames (tracking) starts afresh, as a restarted child does, built for a stall.
        self._local = self._factory()
        return (now - read.started) * 1e3

    def abandon(self) -> int | None:
        """On shutdown: abandon the in-process read in flight, whatever its time, let no other
        start (a worker still decoding a frame would otherwise go on to read it, and be waited
        for), and give the threads of reads abandoned before their priority back where
        permitted. The thread's ``threading.get_ident()``, or None when none is in flight."""
        with self._lock:
            self._closing = True
            # The threads lowered before get the caller's priority back, where the system lets
            # a process raise a priority (root, CAP_SYS_NICE): the kernel ends a process only
            # once each of its threads has run again, which a lowered one waits for.
            normal = os.getpriority(os.PRIO_PROCESS, 0)
            for lowered in self._lowered:
                _set_priority(lowered.native_id, normal)
            self._lowered.clear()
            read = self._read
            if read is None:
                return None
            read.abandoned = True
            self._read = None
            self._stuck += 1
        return read.thread

    def poll_s(self) -> float:
        """How long the watchdog may sleep before calling :meth:`check` again."""
        with self._lock:
            read = self._read
        if read is None:
            return min(_IDLE_POLL_S, self.deadline_s)
        return max(0.001, read.started + self.deadline_s - time.monotonic())


def _set_priority(native_id: int, nice: int) -> bool:
    """Set the nice value of thread ``native_id``; False where not permitted (raising a
    priority needs privileges) or the thread is gone."""
    try:
        os.setpriority(os.PRIO_PROCESS, native_id, nice)
    except OSError:
        return False
    return True
