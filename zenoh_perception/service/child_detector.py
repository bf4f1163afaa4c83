"""Detection under a deadline: the detector runs in a child process, killed when one frame
takes longer than the deadline.

Some frames make OpenCV's ArUco detector slow whatever its parameters: a checkerboard whose
squares sit just above the smallest marker (a tiled floor, a calibration board) gives
thousands of candidate quads, and one HD720 frame takes seconds. A Python thread stuck in
``detectMarkers`` cannot be stopped, so the detector runs in a process of its own:

- :class:`IsolatedDetector` is a :class:`~zenoh_perception.detect.types.Detector`: the grey
  image goes to the child through one shared-memory segment, the detections come back
  through a pipe. :meth:`IsolatedDetector.gray_buffer` is that segment as an array, so that
  the grey conversion writes the image straight into it (no copy); any other image is copied
  in.
- A read that takes longer than ``deadline_s`` (or that is still running when ``stop`` is
  set) kills the child and raises :class:`~zenoh_perception.errors.FrameAbandonedError`; the
  spare child, started and ready beforehand, takes the next frame at once, and a new spare is
  started. A child that dies (a crash inside OpenCV) is replaced the same way.
- Children are forked from multiprocessing's fork server, a clean process that has imported
  this module (OpenCV, numpy) once, not from the service with its Zenoh threads.

The child builds its detector with ``factory`` (picklable: a module-level function or a
``functools.partial`` of one), so whatever detector that builds is the one under the deadline;
a detector keeping state between frames starts afresh after a restart. No Zenoh, no logging.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
import time
from collections.abc import Callable
from contextlib import suppress
from multiprocessing import shared_memory
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import set_opencv_threads
from zenoh_perception.detect.types import Detection, Detector, R
from zenoh_perception.errors import FrameAbandonedError, ProcessingError

#: How often a wait for the child looks at the stop event and the deadline, seconds.
_POLL_S: Final = 0.02
#: What a detector may raise on one frame it cannot read (then the child carries on).
_DETECT_ERRORS: Final = (cv2.error, ValueError)

DetectorFactory = Callable[[], Detector]


def _serve(conn: Connection, factory: DetectorFactory, opencv_threads: int) -> None:
    """The child: its OpenCV threads set, build the detector, say ready, then read one frame
    per request."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when a child ends
    set_opencv_threads(opencv_threads)
    detector = factory()
    segment: shared_memory.SharedMemory | None = None
    conn.send(None)
    while True:
        try:
            name, height, width = conn.recv()
        except EOFError:  # the parent is gone
            return
        if segment is None or segment.name != name:
            if segment is not None:
                segment.close()
            # The fork server's children share the parent's resource tracker: attaching
            # registers nothing new, and the parent unlinks the segment.
            segment = shared_memory.SharedMemory(name=name)
        gray = np.ndarray((height, width), np.uint8, segment.buf)
        try:
            found: list[Detection] | str = detector.detect(gray)
        except _DETECT_ERRORS as err:
            found = f"{type(err).__name__}: {err}"
        del gray  # no view may outlive a segment that closes
        conn.send(found)


class _Child:
    """One child process and the parent's end of its pipe."""

    def __init__(
        self,
        context: multiprocessing.context.BaseContext,
        factory: DetectorFactory,
        opencv_threads: int,
    ):
        self.conn, child_conn = context.Pipe()
        self.process: BaseProcess = context.Process(  # type: ignore[attr-defined]
            target=_serve,
            args=(child_conn, factory, opencv_threads),
            name="perception-detector",
            daemon=True,
        )
        self.process.start()
        child_conn.close()
        self.ready = False

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(timeout=1.0)
        self.conn.close()


class IsolatedDetector(Detector):
    """A detector built by ``factory`` in a child process, each read bounded by
    ``deadline_s``; see the module documentation. Use it from one thread at a time.

    ``after_stall`` (default ``factory``) builds the detector of each spare child: a spare
    takes over only when a read was killed, and may expect the frames that stalled it.

    Raises (from :meth:`detect`):
        FrameAbandonedError: the read took longer than the deadline, or ``stop`` was set.
        ProcessingError: the detector failed on the frame, or its process died (stage
            ``detect``).
    """

    def __init__(
        self,
        factory: DetectorFactory,
        deadline_s: float,
        *,
        stop: threading.Event | None = None,
        after_stall: DetectorFactory | None = None,
        opencv_threads: int = 0,
    ) -> None:
        self.deadline_s = deadline_s
        self._opencv_threads = opencv_threads
        self._factory = factory
        self._after_stall = after_stall if after_stall is not None else factory
        self._stop = stop if stop is not None else threading.Event()
        self._context = multiprocessing.get_context("forkserver")
        # The fork server imports this module and the factory's once: a child starts warm.
        origin = getattr(factory, "func", factory)
        self._context.set_forkserver_preload([__name__, origin.__module__])
        self._segment: shared_memory.SharedMemory | None = None
        self._retired: list[shared_memory.SharedMemory] = []  # unlinked, still mapped
        self._active: _Child | None = None
        self._spare: _Child | None = None
        self.restarts = 0

    def start(self) -> None:
        """Start the child and its spare (the first start also starts the fork server)."""
        if self._active is None:
            self._active = _Child(self._context, self._factory, self._opencv_threads)
        if self._spare is None:
            self._spare = _Child(self._context, self._after_stall, self._opencv_threads)

    def close(self) -> None:
        """Kill the children and free the shared memory."""
        for child in (self._active, self._spare):
            if child is not None:
                child.kill()
        self._active = self._spare = None
        if self._segment is not None:
            self._segment.unlink()
            self._retired.append(self._segment)
            self._segment = None
        for segment in self._retired:
            with suppress(BufferError):  # still viewed: unmapped once the view is gone
                segment.close()
        self._retired = []

    def __enter__(self) -> IsolatedDetector:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        """Every marker the child's detector finds in ``gray``, within the deadline."""
        self.start()
        child = self._active
        assert child is not None  # start() made it
        started = time.monotonic()
        if not child.ready:
            # A fresh child builds its detector; that time is not the frame's.
            if not self._wait(child, None):  # stopped meanwhile
                raise FrameAbandonedError(0.0, self.deadline_s * 1e3)
            self._receive(child)
            child.ready = True
            started = time.monotonic()
        height, width = gray.shape[:2]
        segment = self._segment_for(height * width)
        shared = np.ndarray((height, width), np.uint8, segment.buf)
        if not np.shares_memory(gray, shared):  # not converted into gray_buffer()
            shared[...] = gray
        del shared
        child.conn.send((segment.name, height, width))
        if not self._wait(child, started + self.deadline_s):
            elapsed_ms = (time.monotonic() - started) * 1e3
            self._replace()
            raise FrameAbandonedError(elapsed_ms, self.deadline_s * 1e3)
        found: list[Detection] | str = self._receive(child)
        if isinstance(found, str):
            raise ProcessingError("detect", found)
        return found

    def _receive(self, child: _Child) -> Any:
        """What ``child`` sent; a child that died instead is replaced.

        Raises:
            ProcessingError: the child died (stage ``detect``).

        """
        try:
            return child.conn.recv()
        except (EOFError, OSError) as err:
            child.process.join(timeout=1.0)
            code = child.process.exitcode
            self._replace()
            raise ProcessingError("detect", f"detector process died (exit code {code})") from err

    def _wait(self, child: _Child, until: float | None) -> bool:
        """Whether ``child`` answered (or died) before ``until`` and before ``stop``."""
        while not self._stop.is_set():
            timeout = _POLL_S if until is None else min(_POLL_S, until - time.monotonic())
            if timeout <= 0:
                return False
            if child.conn.poll(timeout):
                return True
        return False

    def _replace(self) -> None:
        """Kill the active child; the spare takes over and a new spare starts."""
        if self._active is not None:
            self._active.kill()
        self._active, self._spare = self._spare, None
        self.restarts += 1
        if not self._stop.is_set():
            self.start()

    def gray_buffer(self, height: int, width: int) -> npt.NDArray[np.uint8]:
        """A (height, width) array in the segment the child reads the next frame from."""
        return np.ndarray((height, width), np.uint8, self._segment_for(height * width).buf)

    def watched(self, read: Callable[[], R]) -> R | None:
        """None: a read in the calling process is not bounded by the child's deadline, so it
        is not taken."""
        return None

    def _segment_for(self, size: int) -> shared_memory.SharedMemory:
        """The shared segment, replaced by one at least twice as large when a frame needs more
        than it holds. The one replaced is unlinked at once but stays mapped until
        :meth:`close`: an array of a past frame (a gray_buffer) may still view it."""
        if self._segment is None or self._segment.size < size:
            if self._segment is not None:
                self._segment.unlink()
                self._retired.append(self._segment)
                size = max(size, 2 * self._segment.size)
            self._segment = shared_memory.SharedMemory(create=True, size=max(size, 1))
        return self._segment
