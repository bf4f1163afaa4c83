"""service/group.py in process: members on Zenoh sessions divide the announced streams, and
no peer's token breaks that (hostile announcements, bare or silent members, members that
disagree, floods of cameras)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from typing import Any, cast

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import wait_until
from zenoh_perception.camera.shm import announce
from zenoh_perception.errors import SettingsError
from zenoh_perception.service.group import (
    SILENT_AFTER_S,
    StreamGroup,
    camera_sources,
    settings_fingerprint,
)
from zenoh_perception.service.stats import LogGate
from zenoh_perception.settings import Settings
from zenoh_perception.sharing import assign, held_by, member_token_key

KEYS = [f"cams/{name}/image" for name in ("a", "b", "c", "d")]
SETTINGS = Settings.from_flat(
    input_key="cams/*/image",
    compressed_input_key="",
    tag_key="out/{stream}/tag",
    record_key="out/{stream}/tags",
    debug_image_key="out/{stream}/debug",
    detections_key="out/{stream}/detections",
)
FINGERPRINT = settings_fingerprint(SETTINGS)


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


class Worker:
    """Stands for the service's worker loop: beats every ``period`` s until ``stop`` (a
    wedged worker: the session lives on, the heartbeat stops). ``stall`` s once in a while
    stands for a busy frame."""

    def __init__(self, group: StreamGroup, *, period: float = 0.1, stall: float = 0.0) -> None:
        self.group = group
        self.stop = threading.Event()
        self.turns = 0
        self._period, self._stall = period, stall
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self.stop.wait(self._stall or self._period):
            self.group.beat()
            self.turns += 1

    def close(self) -> None:
        self.stop.set()
        self._thread.join()


@dataclass
class Member:
    group: StreamGroup
    held: Held
    worker: Worker
    failed: threading.Event


@contextmanager
def member(
    session: zenoh.Session,
    settings: Settings = SETTINGS,
    *,
    stall: float = 0.0,
    start: bool = True,
) -> Iterator[Member]:
    held, failed = Held(), threading.Event()
    group = StreamGroup(
        session,
        name="g",
        liveliness_key="perception/alive",
        sources=camera_sources(settings.inputs, settings.ros),
        fingerprint=settings_fingerprint(settings),
        capacity=settings.inputs.max_streams,
        take=held.take,
        release=held.release,
        gate=LogGate(5.0),
        failed=failed,
        discovery_timeout_s=1.0,
    )
    worker = Worker(group, stall=stall)
    try:
        if start:
            group.start()
        yield Member(group, held, worker, failed)
    finally:
        worker.close()
        group.close()
    assert not failed.is_set()


def test_two_members_split_the_streams_and_one_takes_all_when_the_other_leaves(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    tokens.append(announce(first, "other/x/image"))  # not an input: never held
    zids = [str(first.zid()), str(second.zid())]
    expected = assign(KEYS, zids)
    with member(first) as one:
        wait_until(lambda: one.held.keys == set(KEYS), what="the only member holds every stream")
        with member(second) as two:
            wait_until(
                lambda: (
                    one.held.keys == held_by(expected, zids[0])
                    and two.held.keys == held_by(expected, zids[1])
                ),
                what="the streams split as the assignment says",
            )
            assert len(one.held.keys) == len(two.held.keys) == 2
        # the second left: it released everything, the first took it all back
        assert two.held.keys == set()
        released = [f"release {k}" for k in sorted(held_by(expected, zids[1]))]
        assert two.held.calls[-2:] == released
        wait_until(lambda: one.held.keys == set(KEYS), what="the streams back with the first")
        # a camera that stops is a stream no more
        tokens[0].undeclare()
        wait_until(lambda: one.held.keys == set(KEYS[1:]), what="the stopped camera released")
    assert one.held.keys == set()
    for token in tokens[1:]:
        token.undeclare()


HOSTILE = [
    ("@camera/cams/*/image", "not_concrete"),
    ("@camera/**", "not_concrete"),
    ("@camera/cams/x$*/image", "not_concrete"),
    ("@camera/cams/" + "x" * 300 + "/image", "too_long"),
]


def test_hostile_announcements_are_ignored_counted_and_the_group_keeps_working(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """A wildcard announcement once killed the group's thread (``hold`` raised on it): the
    instance then never reassigned. Now each is ignored and counted by reason, and a member
    that leaves still hands its streams over."""
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    hostile = [first.liveliness().declare_token(key) for key, _ in HOSTILE]
    with member(first) as one:
        with member(second) as two:
            wait_until(
                lambda: len(one.held.keys) == len(two.held.keys) == 2,
                what="the four real cameras split",
            )
            ignored = one.group.status()["ignored"]
            assert ignored == {"not_concrete": 3, "too_long": 1}
            # and later ones too, while the group runs
            hostile.append(first.liveliness().declare_token("@camera/cams/**"))
            wait_until(
                lambda: one.group.status()["ignored"].get("not_concrete") == 4,
                what="the later wildcard counted",
            )
        wait_until(lambda: one.held.keys == set(KEYS), what="the leaver's streams taken over")
        assert one.group.status()["thread_alive"]
        assert one.group.status()["streams"] == len(KEYS)
    for token in [*tokens, *hostile]:
        token.undeclare()


def _bare_token(session: zenoh.Session, zid: str = "abcdef12", fp: str = FINGERPRINT) -> Any:
    """A member token with nothing behind it: no heartbeat, no service."""
    return session.liveliness().declare_token(member_token_key("perception/alive", "g", zid, fp))


def test_a_bare_member_token_never_takes_streams(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """A bare token under the group's key once took its share of the cameras for as long as
    it lived (50 of them took every camera). Without a heartbeat it is no member."""
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    bare = [_bare_token(second, f"abcdef{i:02x}") for i in range(50)]
    with member(first) as one:
        wait_until(lambda: one.held.keys == set(KEYS), what="every stream held despite 50")
        status = one.group.status()
        assert status["members"] == [str(first.zid())]
        assert len(status["silent"]) == 50
    for token in [*tokens, *bare]:
        token.undeclare()


def test_a_member_whose_worker_stops_loses_its_streams_to_the_others(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """A wedged member (its worker loop stopped, its Zenoh session alive and its token
    declared) once kept its cameras unanswered for as long as it lived. Its heartbeat stops
    with its worker: the others take its streams once it is silent for SILENT_AFTER_S."""
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    with member(first) as one, member(second) as two:
        wait_until(lambda: len(one.held.keys) == 2, what="the streams split")
        two.worker.close()  # wedged: the session and the token live on
        wedged_at = time.monotonic()
        wait_until(lambda: one.held.keys == set(KEYS), what="the wedged member's streams taken")
        took_s = time.monotonic() - wedged_at
        print(f"silent member's streams taken {took_s * 1e3:.0f} ms after its worker stopped")
        status = one.group.status()
        assert status["silent"] == [str(second.zid())]
        assert status["evictions"] == 1
        # its worker back: it is a member again, and the streams split again
        two.worker = Worker(two.group)
        wait_until(lambda: len(one.held.keys) == 2, what="the member back takes its share")
    for token in tokens:
        token.undeclare()


def test_a_busy_member_and_one_whose_cameras_are_silent_are_never_evicted(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """A worker that stalls 400 ms between turns (a slow frame) beats between frames, and a
    member whose cameras send nothing still beats on every idle poll: neither is evicted."""
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    with member(first) as one, member(second, stall=0.4) as busy:
        wait_until(lambda: len(one.held.keys) == len(busy.held.keys) == 2, what="the split")
        split = set(busy.held.keys)
        turns = busy.worker.turns
        # some seconds of stalls, past the silence bound
        wait_until(
            lambda: busy.worker.turns >= turns + int(SILENT_AFTER_S / 0.4) * 2,
            what="stalls for twice the silence bound",
        )
        assert one.group.status()["evictions"] == 0
        assert busy.held.keys == split
    for token in tokens:
        token.undeclare()


def test_an_instance_refuses_to_join_members_that_serve_other_settings(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """One instance on a pattern, another on a list of two of its cameras (or another
    max_streams) once split the cameras, leaving some unanswered. The newcomer now refuses to
    join and names the setting that differs; the member there names it in its status."""
    first, second = peers
    listed = SETTINGS.with_flat(input_key=("cams/a/image", "cams/b/image"), max_streams=8)
    tokens = [announce(first, key) for key in KEYS]
    with member(first) as one:
        wait_until(lambda: one.held.keys == set(KEYS), what="the first holds every stream")
        with (
            pytest.raises(SettingsError, match=r"another input_key, max_streams"),
            member(second, listed),
        ):
            pass
        assert one.held.keys == set(KEYS)
        # one that joins anyway (its token there, beating) is left out and named
        other = settings_fingerprint(SETTINGS.with_flat(dictionary="DICT_5X5_100"))
        with ExitStack() as stack:
            stack.callback(_bare_token(second, "abcdef99", other).undeclare)
            publisher = second.declare_publisher("perception/alive/group/g/beat/abcdef99")
            stack.callback(publisher.undeclare)
            wait_until(
                lambda: (
                    (publisher.put(b""), one.group.status()["disagreeing"])[1]
                    == {"abcdef99": ["dictionary"]}
                ),
                what="the disagreeing member named",
            )
            assert one.held.keys == set(KEYS)
    for token in tokens:
        token.undeclare()


def test_announced_streams_beyond_the_bound_cost_a_counter_and_churn_leaves_nothing(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """1,200 cameras announced: a member holds max_streams of them, keeps at most 1,024, and
    counts the rest; once they go, nothing of them is left (no set of every camera ever
    announced)."""
    first, second = peers
    tokens = [announce(first, f"cams/{i}/image") for i in range(1200)]
    with member(second) as one:
        wait_until(
            lambda: (
                one.group.status()["streams"] == 1024
                and len(one.held.keys) == SETTINGS.inputs.max_streams
            ),
            what="1,024 streams kept, max_streams held",
        )
        wait_until(  # the announcements past the bound may still be arriving
            lambda: one.group.status()["ignored"].get("too_many_announced") == 176,
            what="the 176 past the bound counted",
        )
        for token in tokens:
            token.undeclare()
        wait_until(lambda: one.group.status()["streams"] == 0, what="every stream gone")
        wait_until(lambda: not one.held.keys, what="every stream released")
        # unique short-lived cameras, one after another
        for i in range(500):
            announce(first, f"cams/u{i}/image").undeclare()
        late = announce(first, "cams/last/image")
        wait_until(lambda: one.held.keys == {"cams/last/image"}, what="the churn applied")
        assert one.group.status()["streams"] == 1
        late.undeclare()


@dataclass(frozen=True)
class FakeSample:
    """What the group's handlers read of a sample: its key and kind."""

    key_expr: str
    kind: zenoh.SampleKind


_CHUNK = st.one_of(
    st.sampled_from(["*", "**", "$*", "cams", "image", "@camera", "perception", "alive"]),
    st.sampled_from(["group", "g", "member", "beat", "abcdef12", FINGERPRINT, "", "a" * 300]),
    st.text(min_size=0, max_size=12),
)
_KEYS = st.lists(_CHUNK, min_size=1, max_size=20).map("/".join)
_PREFIXES = st.sampled_from(
    [
        "",
        "@camera/",
        "@camera/cams/",
        "perception/alive/group/g/member/",
        "perception/alive/group/g/beat/",
    ]
)


@given(st.lists(st.tuples(_PREFIXES, _KEYS, st.booleans()), max_size=30))
def test_random_liveliness_keys_never_raise_in_the_groups_handlers(
    samples: list[tuple[str, str, bool]],
) -> None:
    session = cast(Any, _FakeSession())
    group = StreamGroup(
        session,
        name="g",
        liveliness_key="perception/alive",
        sources=camera_sources(SETTINGS.inputs, SETTINGS.ros),
        fingerprint=FINGERPRINT,
        capacity=4,
        take=lambda _key: None,
        release=lambda _key: None,
        gate=LogGate(60.0),
        failed=threading.Event(),
    )
    on_camera = [group._camera_callback(s) for s in group._sources]
    handlers = [group._on_member, group._on_beat, *on_camera]
    for prefix, key, put in samples:
        kind = zenoh.SampleKind.PUT if put else zenoh.SampleKind.DELETE
        sample = cast(zenoh.Sample, FakeSample(prefix + key, kind))
        for handler in handlers:
            handler(sample)
    live, streams = group._sets()
    assert live == {"0123abcd"}
    assert len(streams) <= 1024


class _FakeSession:
    def zid(self) -> str:
        return "0123abcd"


def test_a_crash_of_the_groups_thread_fails_the_service_loudly(
    peers: tuple[zenoh.Session, zenoh.Session], caplog: pytest.LogCaptureFixture
) -> None:
    """The group's thread once died silently (``event=thread_crashed``, nothing else): the
    instance then never reassigned while its status said it was alive. A crash now sets
    ``failed`` (``run`` exits 1) and the status says the thread is gone."""
    first, _second = peers
    token = announce(first, KEYS[0])
    failed = threading.Event()

    def take(_key: str) -> None:
        raise RuntimeError("a bug")

    group = StreamGroup(
        first,
        name="g",
        liveliness_key="perception/alive",
        sources=camera_sources(SETTINGS.inputs, SETTINGS.ros),
        fingerprint=FINGERPRINT,
        capacity=4,
        take=take,
        release=lambda _key: None,
        gate=LogGate(5.0),
        failed=failed,
        discovery_timeout_s=1.0,
    )
    group.start()
    try:
        wait_until(failed.is_set, what="the crash reported")
        wait_until(lambda: not group.status()["thread_alive"], what="the thread gone")
        assert "event=thread_crashed" in caplog.text
        assert "thread=perception-group" in caplog.text
    finally:
        group.close()
        token.undeclare()


def test_a_flood_of_bare_member_tokens_cannot_shut_a_real_member_out(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    """200 bare member tokens (64 once filled a group's table) leave the real members
    counted: they split the streams as if alone."""
    first, second = peers
    tokens = [announce(first, key) for key in KEYS]
    bare = [_bare_token(first, f"abcd{i:04x}") for i in range(200)]
    with member(first) as one:
        wait_until(lambda: one.held.keys == set(KEYS), what="every stream held")
        with member(second) as two:
            wait_until(
                lambda: len(one.held.keys) == len(two.held.keys) == 2,
                what="the real members split the streams",
            )
    for token in [*tokens, *bare]:
        token.undeclare()
