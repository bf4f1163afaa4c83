"""service/mailbox.py: the stream whose newest frame waited longest first, one worker per
stream at a time, newest frame wins within a stream."""

from __future__ import annotations

import threading

from tests.helpers import wait_until
from zenoh_perception.service.mailbox import Scheduler


def test_the_stream_whose_frame_waited_longest_is_taken_first() -> None:
    scheduler: Scheduler[str, int] = Scheduler()
    lanes = {name: scheduler.lane(name) for name in ("a", "b", "c")}
    scheduler.put(lanes["b"], 1, at_ns=30)
    scheduler.put(lanes["a"], 2, at_ns=20)
    scheduler.put(lanes["c"], 3, at_ns=10)
    taken = [scheduler.take(0) for _ in range(3)]
    assert [(t[0].owner, t[1]) for t in taken if t is not None] == [("c", 3), ("a", 2), ("b", 1)]
    assert scheduler.take(0) is None


def test_a_stream_is_held_by_one_worker_until_done_and_its_newest_frame_wins() -> None:
    scheduler: Scheduler[str, int] = Scheduler()
    lane = scheduler.lane("a")
    assert scheduler.put(lane, 1, at_ns=1) is False
    taken = scheduler.take(0)
    assert taken is not None and taken[1] == 1
    assert scheduler.put(lane, 2, at_ns=2) is False
    assert scheduler.put(lane, 3, at_ns=3) is True  # 2 was never taken: dropped
    assert scheduler.take(0) is None  # held: no second worker on the same stream
    assert scheduler.done(lane) is False
    again = scheduler.take(0)
    assert again is not None and again[1] == 3


def test_a_slow_stream_leaves_the_others_to_another_worker() -> None:
    scheduler: Scheduler[str, int] = Scheduler()
    slow, quick = scheduler.lane("slow"), scheduler.lane("quick")
    scheduler.put(slow, 1, at_ns=1)
    first = scheduler.take(0)
    assert first is not None and first[0] is slow
    scheduler.put(slow, 2, at_ns=2)
    scheduler.put(quick, 1, at_ns=3)
    second = scheduler.take(0)  # the slow one is busy: the quick one goes
    assert second is not None and second[0] is quick


def test_removing_a_busy_lane_tells_its_worker_and_close_wakes_every_worker() -> None:
    scheduler: Scheduler[str, int] = Scheduler()
    lane = scheduler.lane("a")
    scheduler.put(lane, 1, at_ns=1)
    assert scheduler.take(0) is not None
    assert scheduler.remove(lane) is False  # a worker holds it
    assert scheduler.put(lane, 2, at_ns=2) is False  # ignored
    assert scheduler.done(lane) is True  # the worker closes the stream
    idle = scheduler.lane("b")
    assert scheduler.remove(idle) is True
    results: list[object] = []
    workers = [
        threading.Thread(target=lambda: results.append(scheduler.take(None))) for _ in range(2)
    ]
    for worker in workers:
        worker.start()
    scheduler.close()
    for worker in workers:
        worker.join(timeout=10)
    wait_until(lambda: len(results) == 2, what="both workers woken")
    assert results == [None, None]
