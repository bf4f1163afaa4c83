"""The service's worker threads, which answer the streams' frames.

Each worker takes the stream whose newest frame has waited longest, one worker per stream at
a time (:mod:`~zenoh_perception.service.mailbox`), and answers that frame
(:meth:`~zenoh_perception.service.stream.Stream.handle`).

With ``frame_deadline_ms`` the watchdog (:mod:`~zenoh_perception.service.watchdog`) may
abandon a worker inside a stalled read: :meth:`Workers.replace` starts another in its place
and the stuck one ends on its own.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from typing import Final

import zenoh

from zenoh_perception.errors import SessionError, zenoh_error_text
from zenoh_perception.service.guard import StaleDetection
from zenoh_perception.service.mailbox import Scheduler
from zenoh_perception.service.stream import Arrival, Stream

log = logging.getLogger(__name__)

#: Rejection reason of a frame whose stream's outputs Zenoh refused to declare.
STREAM_REFUSED: Final = "stream_refused"
#: How long a worker waits for a frame before it looks at ``stop`` again, seconds.
_POLL_S = 0.1


def usable_cpus() -> set[int]:
    """The CPUs this process may run on."""
    try:
        return os.sched_getaffinity(0)
    except AttributeError:  # not Linux
        return set(range(os.cpu_count() or 1))


class Workers:
    """The worker threads of one service.

    A worker that dies of anything unforeseen sets ``failed``; every worker ends once ``stop``
    is set.
    """

    def __init__(
        self,
        scheduler: Scheduler[Stream, Arrival],
        stop: threading.Event,
        failed: threading.Event,
        *,
        pulse: Callable[[], None] = lambda: None,
    ) -> None:
        self._scheduler = scheduler
        self._stop = stop
        self._failed = failed
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

    def replace(self, stuck: int | None) -> None:
        """Start a worker in place of ``stuck`` (a thread id), left inside a read the
        watchdog abandoned: it ends on its own."""
        self._abandoned.add(stuck)
        self.start_one()

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
