"""The service's worker threads, which answer the streams' frames, and its watchdog, which
abandons a detection past ``frame_deadline_ms`` and starts a worker in its place.

Each worker takes the stream whose newest frame has waited longest, one worker per stream at
a time (:mod:`~zenoh_perception.service.mailbox`), and answers that frame
(:meth:`~zenoh_perception.service.stream.Stream.handle`).

With ``frame_deadline_ms`` a frame the detector does not finish in time is abandoned (a
rejection, counted with its time) and the stream's newest frame read next by a fresh
detector. By default (``detector_process = "on_stall"``) detection runs in the worker and the
watchdog abandons a read past the deadline, leaves that worker to end on its own and starts
another (:mod:`~zenoh_perception.service.guard`); for a while after, the stream's frames go to
a child process that is killed on a stall (:mod:`~zenoh_perception.service.watchdog`), as
every frame does with ``"always"``.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from typing import Final

import zenoh

from zenoh_perception.errors import (
    FrameAbandonedError,
    ProcessingError,
    SessionError,
    zenoh_error_text,
)
from zenoh_perception.service.guard import StaleDetection
from zenoh_perception.service.mailbox import Scheduler
from zenoh_perception.service.stream import Arrival, Stream

# the service's logger: its lines keep one logger= name, whatever module writes them
log = logging.getLogger("zenoh_perception.service.node")

#: Rejection reason of a frame whose stream's outputs Zenoh refused to declare.
STREAM_REFUSED: Final = "stream_refused"
_POLL_S = 0.1


def usable_cpus() -> set[int]:
    """The CPUs this process may run on."""
    try:
        return os.sched_getaffinity(0)
    except AttributeError:  # not Linux
        return set(range(os.cpu_count() or 1))


class Workers:
    """The worker threads of one service, and the watchdog's loop (:meth:`watch`).

    A worker that dies of anything unforeseen sets ``failed``; every loop ends once ``stop``
    is set. ``guarded`` lists the streams whose detection a deadline guards.
    """

    def __init__(
        self,
        scheduler: Scheduler[Stream, Arrival],
        stop: threading.Event,
        failed: threading.Event,
        guarded: Callable[[], list[Stream]],
        *,
        pulse: Callable[[], None] = lambda: None,
    ) -> None:
        self._scheduler = scheduler
        self._stop = stop
        self._failed = failed
        self._guarded = guarded
        #: Called on every turn of every worker's loop (a share group's heartbeat: it stops
        #: when the workers stop).
        self._pulse = pulse
        self._workers: list[threading.Thread] = []
        #: Workers whose read the watchdog abandoned (each ends on its own).
        self._abandoned: set[int | None] = set()

    def start_one(self) -> None:
        """Start a worker thread."""
        worker = threading.Thread(target=self._work, name="perception-worker", daemon=True)
        # only the current workers and the abandoned ones still running are kept
        self._workers = [w for w in self._workers if w.is_alive()] + [worker]
        worker.start()

    def running(self, stuck: set[int | None]) -> list[threading.Thread]:
        """The workers alive now, but those in ``stuck`` or abandoned before (each ends on its
        own: a worker inside OpenCV is not waited for)."""
        stuck = stuck | self._abandoned
        current = [w for w in self._workers if w.is_alive()]
        return [w for w in current if w.ident not in stuck]

    def _work(self) -> None:
        replaced = False
        try:
            while not self._stop.is_set():
                self._pulse()
                taken = self._scheduler.take(_POLL_S)
                if taken is None:
                    continue
                lane, arrival = taken
                stream = lane.owner
                stream.worker = threading.get_ident()
                try:
                    stream.handle(arrival)
                except zenoh.ZError as err:  # the stream's outputs could not be declared
                    stream.reject(STREAM_REFUSED, SessionError(zenoh_error_text(err)))
                if self._scheduler.done(lane):
                    stream.close()  # forgotten while this worker answered its frame
        except StaleDetection:
            # The watchdog abandoned this thread's frame and another worker took over: end
            # without touching anything else.
            replaced = True
        finally:
            if not replaced and not self._stop.is_set():
                # Anything unforeseen: say so, and let run() exit non-zero rather than keep
                # a liveliness token that claims a service that answers nothing.
                log.error("event=worker_died")
                self._failed.set()

    def watch(self) -> None:
        """Abandon an in-process detection past the deadline, and start another worker."""
        wait = _POLL_S
        while not self._stop.wait(wait):
            guarded = self._guarded()
            wait = _POLL_S
            for stream in guarded:
                guard = stream.guard
                assert guard is not None
                elapsed_ms = guard.check()
                if elapsed_ms is None:
                    wait = min(wait, guard.poll_s())
                    continue
                err = FrameAbandonedError(elapsed_ms, guard.deadline_s * 1e3)
                stream.stats.on_abandoned(elapsed_ms)
                if guard.abandoned_answered:
                    # the second look after the frame's tag: answered, its record lost
                    stream.processing_failed(ProcessingError("second_look", err))
                else:
                    stream.reject(err.reason, err)
                self._abandoned.add(stream.worker)
                self.start_one()
                # the stuck worker ends on its own: the stream is free for the next frame
                if self._scheduler.done(stream.lane):
                    stream.close()
