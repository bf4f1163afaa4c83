"""Newest-frame-wins mailboxes, one per stream, and their fair hand-off to a few workers.

Zenoh delivers samples on its own threads; the workers must never fall behind. Each stream has
a :class:`Lane`: a one-slot mailbox (``put`` replaces a
frame nobody took, counted as dropped, so no backlog forms whatever the input rate). Workers
call :meth:`Scheduler.take`, which hands out the lane whose newest frame has waited longest
among the lanes that have one and that no worker holds; the lane stays held by that worker
until :meth:`Scheduler.done`, so a stream is read by one worker at a time (its detector state
is not thread-safe) while other streams go to the other workers. A stream that takes long per
frame (a large camera) thus occupies one worker at most: the other streams keep the rest.

``put`` is O(1) and never blocks for long (Zenoh's callback threads call it); ``take`` looks
at the lanes ready now (at most one per stream). No Zenoh, no logging.
"""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

O = TypeVar("O")  # noqa: E741 - the lane's owner (a stream)
I = TypeVar("I")  # noqa: E741 - what a lane carries (a frame's arrival)


class Lane(Generic[O, I]):
    """One stream's slot; its fields are the scheduler's, read under its lock."""

    __slots__ = ("at_ns", "busy", "closed", "item", "owner")

    def __init__(self, owner: O) -> None:
        self.owner = owner
        self.item: I | None = None
        self.at_ns = 0  # when the item in the slot arrived (monotonic ns)
        self.busy = False  # a worker holds the lane
        self.closed = False  # removed: takes nothing more


class Scheduler(Generic[O, I]):
    """The lanes of every stream and the workers' hand-off; see the module documentation."""

    def __init__(self) -> None:
        self._cond = threading.Condition(threading.Lock())
        # lanes with a frame that no worker holds (a dict: insertion-ordered, O(1) removal)
        self._ready: dict[Lane[O, I], None] = {}
        self._closed = False

    def lane(self, owner: O) -> Lane[O, I]:
        """A new lane for ``owner``."""
        return Lane(owner)

    def put(self, lane: Lane[O, I], item: I, at_ns: int) -> bool:
        """Leave ``item`` (arrived at ``at_ns``) in ``lane``; True when it replaced a frame
        nobody took (a dropped frame)."""
        with self._cond:
            if self._closed or lane.closed:
                return False
            replaced = lane.item is not None
            lane.item, lane.at_ns = item, at_ns
            if not lane.busy and not replaced:
                self._ready[lane] = None
                self._cond.notify()
            return replaced

    def take(self, timeout: float | None = None) -> tuple[Lane[O, I], I] | None:
        """The lane whose frame waited longest, held by the caller until :meth:`done`, and
        that frame; None after ``timeout`` s without one, or once closed."""
        with self._cond:
            if not self._ready and not self._closed:
                self._cond.wait(timeout)
            if self._closed or not self._ready:
                return None
            lane = (
                min(self._ready, key=_arrival) if len(self._ready) > 1 else next(iter(self._ready))
            )
            del self._ready[lane]
            item = lane.item
            assert item is not None  # a ready lane holds a frame
            lane.item, lane.busy = None, True
            return lane, item

    def done(self, lane: Lane[O, I]) -> bool:
        """The caller is through with ``lane``'s frame; True when the lane was removed
        meanwhile (the caller then closes what the stream holds)."""
        with self._cond:
            lane.busy = False
            if lane.closed:
                return True
            if lane.item is not None:
                self._ready[lane] = None
                self._cond.notify()
            return False

    def remove(self, lane: Lane[O, I]) -> bool:
        """Take nothing more from ``lane`` (its frame, if any, is dropped); True when no
        worker holds it (the caller closes the stream now), False when one does (that worker
        learns it from :meth:`done`)."""
        with self._cond:
            lane.closed = True
            lane.item = None
            self._ready.pop(lane, None)
            return not lane.busy

    def close(self) -> None:
        """Wake every worker; later takes return None and puts are ignored."""
        with self._cond:
            self._closed = True
            self._ready.clear()
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


def _arrival(lane: Lane[O, I]) -> int:
    return lane.at_ns
