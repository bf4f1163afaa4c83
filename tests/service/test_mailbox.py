"""The latest-frame-wins mailbox between Zenoh's threads and the worker."""

from __future__ import annotations

import threading

from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.service.mailbox import LatestMailbox


def test_mailbox_keeps_only_the_newest_and_counts_drops() -> None:
    box: LatestMailbox[int] = LatestMailbox()
    assert box.put(1) is False
    assert box.put(2) is True
    assert box.put(3) is True
    assert box.take(0.0) == 3
    assert box.take(0.0) is None
    assert box.dropped == 2


def test_mailbox_wakes_a_waiting_consumer_and_close_releases_it() -> None:
    box: LatestMailbox[str] = LatestMailbox()
    got: list[str | None] = []
    consumer = threading.Thread(target=lambda: got.append(box.take(10.0)))
    consumer.start()
    box.put("frame")
    consumer.join(10.0)
    assert got == ["frame"]
    closer = threading.Thread(target=lambda: got.append(box.take(10.0)))
    closer.start()
    box.close()
    closer.join(10.0)
    assert got == ["frame", None] and not closer.is_alive()
    assert box.put("late") is False and box.take(0.0) is None


@given(st.lists(st.one_of(st.integers(min_value=0), st.none()), max_size=40))
def test_any_puts_and_takes_behave_as_one_slot_that_keeps_the_newest(
    ops: list[int | None],
) -> None:
    """Each int is put, each None is a take: the take gets the newest item not yet taken, and
    every item replaced before it was taken counts as dropped."""
    box: LatestMailbox[int] = LatestMailbox()
    slot: int | None = None
    dropped = 0
    for op in ops:
        if op is None:
            assert box.take(0.0) == slot
            slot = None
        else:
            assert box.put(op) is (slot is not None)
            dropped += slot is not None
            slot = op
    assert box.dropped == dropped
    assert box.take(0.0) == slot


def test_take_times_out_empty_handed() -> None:
    box: LatestMailbox[int] = LatestMailbox()
    assert box.take(0.01) is None
    assert not box.closed
    box.close()
    assert box.closed
