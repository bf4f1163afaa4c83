"""The watchdog loop: with ``frame_deadline_ms``, a detection past the deadline is abandoned
and a worker started in place of the one stuck inside it.

A frame the detector does not finish in time is abandoned (a rejection, counted with its
time) and the stream's newest frame read next by a fresh detector. By default
(``detector_process = "on_stall"``) detection runs in the worker, guarded
(:mod:`~zenoh_perception.service.guard`): this loop asks each guarded stream to check its
deadline (:meth:`~zenoh_perception.service.stream.Stream.check_deadline`), and for a read
past it starts another worker and leaves the stuck one to end on its own; for a while after,
the stream's frames go to a child process that is killed on a stall
(:mod:`~zenoh_perception.service.child_detector`), as every frame does with ``"always"``
(which needs no loop here).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Final

from zenoh_perception.service.mailbox import Scheduler
from zenoh_perception.service.stream import Arrival, Stream
from zenoh_perception.service.workers import Workers

#: Longest sleep between two looks at the guarded streams, seconds.
POLL_S: Final = 0.1


def watch(
    guarded: Callable[[], list[Stream]],
    workers: Workers,
    scheduler: Scheduler[Stream, Arrival],
    stop: threading.Event,
) -> None:
    """Until ``stop``: abandon each in-process detection of the ``guarded`` streams past its
    deadline, and start another worker in place of the one left inside it."""
    wait = POLL_S
    while not stop.wait(wait):
        streams = guarded()
        wait = POLL_S
        for stream in streams:
            stall = stream.check_deadline()
            if stall is None:
                assert stream.guard is not None
                wait = min(wait, stream.guard.poll_s())
                continue
            workers.replace(stall.worker)
            # the stuck worker ends on its own: the stream is free for the next frame
            if scheduler.done(stream.lane):
                stream.close()
