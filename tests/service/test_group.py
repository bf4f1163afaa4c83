"""service/group.py in process: members on two Zenoh sessions divide the announced streams."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import zenoh

from tests.helpers import wait_until
from zenoh_perception.camera.shm import announce
from zenoh_perception.service.group import StreamGroup
from zenoh_perception.sharing import assign, held_by

KEYS = [f"cams/{name}/image" for name in ("a", "b", "c", "d")]


class Held:
    """What ``take`` and ``release`` left held, in order."""

    def __init__(self) -> None:
        self.keys: set[str] = set()
        self.calls: list[str] = []
        self.lock = threading.Lock()

    def take(self, key: str) -> None:
        with self.lock:
            assert key not in self.keys
            self.keys.add(key)
            self.calls.append(f"take {key}")

    def release(self, key: str) -> None:
        with self.lock:
            self.keys.remove(key)
            self.calls.append(f"release {key}")


@contextmanager
def member(session: zenoh.Session, held: Held, patterns: list[str]) -> Iterator[StreamGroup]:
    group = StreamGroup(
        session,
        name="g",
        liveliness_key="perception/alive",
        patterns=patterns,
        take=held.take,
        release=held.release,
    )
    group.start()
    try:
        yield group
    finally:
        group.close()


def test_two_members_split_the_streams_and_one_takes_all_when_the_other_leaves(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    tokens.append(announce(first, "other/x/image"))  # not an input: never held
    one, two = Held(), Held()
    zids = [str(first.zid()), str(second.zid())]
    expected = assign(KEYS, zids)
    with member(first, one, ["cams/*/image"]):
        wait_until(lambda: one.keys == set(KEYS), what="the only member holds every stream")
        with member(second, two, ["cams/*/image"]):
            wait_until(
                lambda: (
                    one.keys == held_by(expected, zids[0])
                    and two.keys == held_by(expected, zids[1])
                ),
                what="the streams split as the assignment says",
            )
            assert len(one.keys) == len(two.keys) == 2
        # the second left: it released everything, the first took it all back
        assert two.keys == set()
        assert two.calls[-2:] == [f"release {k}" for k in sorted(held_by(expected, zids[1]))]
        wait_until(lambda: one.keys == set(KEYS), what="the streams back with the first")
        # a camera that stops is a stream no more
        tokens[0].undeclare()
        wait_until(lambda: one.keys == set(KEYS[1:]), what="the stopped camera released")
    assert one.keys == set()
    for token in tokens[1:]:
        token.undeclare()
