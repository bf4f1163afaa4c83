"""The share group's assignment: balance, determinism, and few moves when members change."""

from __future__ import annotations

import random
from collections import Counter

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from zenoh_perception.errors import AnnouncementError
from zenoh_perception.sharing import (
    GROUP_SETTINGS,
    MAX_ANNOUNCED_CHUNKS,
    MAX_ANNOUNCED_KEY_CHARS,
    LiveStreams,
    assign,
    beat_key,
    beat_of,
    camera_key_of,
    camera_token_key,
    check_announced_key,
    differing,
    fingerprint,
    held_by,
    member_of,
    member_token_key,
    weight,
)

stream_names = st.lists(
    st.from_regex(r"cams/[a-z0-9]{1,8}/image", fullmatch=True), max_size=40, unique=True
)
member_names = st.lists(
    st.from_regex(r"[0-9a-f]{8,32}", fullmatch=True), min_size=1, max_size=9, unique=True
)


def moved(before: dict[str, str], after: dict[str, str]) -> set[str]:
    return {s for s in before if s in after and before[s] != after[s]}


@given(stream_names, member_names)
def test_every_stream_has_one_member_and_loads_differ_by_at_most_one(
    streams: list[str], members: list[str]
) -> None:
    holder = assign(streams, members)
    assert set(holder) == set(streams)
    assert set(holder.values()) <= set(members)
    loads = Counter(holder.values())
    low, high = divmod(len(streams), len(members))
    for member in members:
        assert loads[member] in {low, low + (high > 0)}
    assert sum(len(held_by(holder, m)) for m in members) == len(streams)


@given(stream_names, member_names, st.randoms(use_true_random=False))
def test_order_and_repeats_do_not_matter(
    streams: list[str], members: list[str], rnd: random.Random
) -> None:
    shuffled_streams = [*streams, *streams[:3]]
    shuffled_members = [*members, *members[:1]]
    rnd.shuffle(shuffled_streams)
    rnd.shuffle(shuffled_members)
    assert assign(shuffled_streams, shuffled_members) == assign(streams, members)


def test_the_weight_is_the_same_in_every_process() -> None:
    # a fixed value: a salted or platform-dependent hash would split streams differently
    # in two processes
    assert weight("a1", "cams/front/image") == weight("a1", "cams/front/image")
    assert weight("a1", "cams/front/image") == 0xE72295C3CD2B7423


def _plain_rendezvous(streams: list[str], members: list[str]) -> dict[str, str]:
    return {s: max(members, key=lambda m: (weight(m, s), m)) for s in streams}


def _balanced(holder: dict[str, str], streams: list[str], members: list[str]) -> bool:
    low, extra = divmod(len(streams), len(members))
    loads = Counter(holder.values())
    return all(loads[m] in {low, low + (extra > 0)} for m in members) and (
        sum(loads[m] == low + 1 for m in members) == extra or extra == 0
    )


@given(
    st.lists(st.from_regex(r"cam[0-9]{1,3}", fullmatch=True), max_size=8, unique=True),
    st.lists(st.from_regex(r"[0-9a-f]{4}", fullmatch=True), min_size=2, max_size=4, unique=True),
    st.data(),
)
def test_a_member_leaving_gives_up_only_its_own_streams_where_rendezvous_is_balanced(
    streams: list[str], members: list[str], data: st.DataObject
) -> None:
    leaver = data.draw(st.sampled_from(members))
    staying = [m for m in members if m != leaver]
    before, after = _plain_rendezvous(streams, members), _plain_rendezvous(streams, staying)
    assume(_balanced(before, streams, members) and _balanced(after, streams, staying))
    old, new = assign(streams, members), assign(streams, staying)
    assert old == before
    assert new == after
    assert moved(old, new) == held_by(old, leaver)


@given(
    st.lists(st.from_regex(r"cam[0-9]{1,3}", fullmatch=True), max_size=8, unique=True),
    st.lists(st.from_regex(r"[0-9a-f]{4}", fullmatch=True), min_size=1, max_size=3, unique=True),
    st.from_regex(r"[g-z]{4}", fullmatch=True),
)
def test_a_member_joining_takes_only_its_own_streams_where_rendezvous_is_balanced(
    streams: list[str], members: list[str], joiner: str
) -> None:
    joined = [*members, joiner]
    before, after = _plain_rendezvous(streams, members), _plain_rendezvous(streams, joined)
    assume(_balanced(before, streams, members) and _balanced(after, streams, joined))
    old, new = assign(streams, members), assign(streams, joined)
    assert moved(old, new) == held_by(new, joiner)


@given(stream_names, member_names, st.data())
def test_a_leave_hands_over_every_stream_of_the_leaver(
    streams: list[str], members: list[str], data: st.DataObject
) -> None:
    assume(len(members) >= 2)
    leaver = data.draw(st.sampled_from(members))
    staying = [m for m in members if m != leaver]
    old, new = assign(streams, members), assign(streams, staying)
    assert held_by(old, leaver) <= moved(old, new)
    assert not held_by(new, leaver)


def test_moves_stay_close_to_the_fewest_possible() -> None:
    """Over many random fleets, a change of members moves few streams more than the fewest
    any balanced assignment could (figures in docs/benchmarks.md)."""
    rnd = random.Random(7)
    needed = extra = 0
    for _ in range(300):
        streams = [f"cams/{rnd.randrange(10**6)}/image" for _ in range(rnd.randint(1, 24))]
        members = [f"{rnd.randrange(16**8):08x}" for _ in range(rnd.randint(2, 6))]
        old = assign(streams, members)
        for staying in ([m for m in members if m != leaver] for leaver in members):
            count = len(moved(old, assign(streams, staying)))
            fewest = _fewest_moves(old, streams, staying)
            assert count >= fewest
            needed += fewest
            extra += count - fewest
    assert extra <= needed // 2


def _fewest_moves(old: dict[str, str], streams: list[str], members: list[str]) -> int:
    """The fewest streams any balanced assignment over ``members`` must move from ``old``."""
    low, extra = divmod(len(streams), len(members))
    loads = sorted((len(held_by(old, m)) for m in members), reverse=True)
    kept = sum(min(load, low + (i < extra)) for i, load in enumerate(loads))
    return len(streams) - kept


def test_no_member_no_holder() -> None:
    assert assign(["cams/a/image"], []) == {}
    assert assign([], ["a"]) == {}


FINGERPRINT = fingerprint(dict.fromkeys(GROUP_SETTINGS, "x"))


def test_token_keys_round_trip() -> None:
    assert camera_token_key("cams/front/image") == "@camera/cams/front/image"
    assert camera_key_of("@camera/cams/front/image") == "cams/front/image"
    assert camera_key_of("perception/alive/x") is None
    token = member_token_key("perception/alive", "rover", "a1b2", FINGERPRINT)
    assert token == f"perception/alive/group/rover/member/a1b2/{FINGERPRINT}"
    assert member_of(token, "perception/alive", "rover") == ("a1b2", FINGERPRINT)
    beat = beat_key("perception/alive", "rover", "a1b2")
    assert beat_of(beat, "perception/alive", "rover") == "a1b2"


@pytest.mark.parametrize(
    "token",
    [
        f"perception/alive/group/other/member/a1b2/{FINGERPRINT}",  # another group
        "perception/alive/group/rover/member/a1b2",  # no fingerprint (a bare token)
        f"perception/alive/group/rover/member/a1b2/{FINGERPRINT}/x",
        f"perception/alive/group/rover/member/A1B2/{FINGERPRINT}",  # not a Zenoh id
        "perception/alive/group/rover/member/a1b2/0.1.2.3.4",
        "perception/alive/group/rover/member/*/*",
    ],
)
def test_a_malformed_member_token_is_refused_by_reason(token: str) -> None:
    with pytest.raises(AnnouncementError) as caught:
        member_of(token, "perception/alive", "rover")
    assert caught.value.reason == "bad_member_token"


@pytest.mark.parametrize(
    ("key", "reason"),
    [
        ("rover/*/image", "not_concrete"),
        ("rover/**", "not_concrete"),
        ("rover/$*x/image", "not_concrete"),
        ("", "not_concrete"),
        ("a" * (MAX_ANNOUNCED_KEY_CHARS + 1), "too_long"),
        ("/".join(["a"] * (MAX_ANNOUNCED_CHUNKS + 1)), "too_many_chunks"),
    ],
)
def test_an_announced_key_that_is_no_camera_key_is_refused_by_reason(key: str, reason: str) -> None:
    with pytest.raises(AnnouncementError) as caught:
        check_announced_key(key)
    assert caught.value.reason == reason


def test_a_fingerprint_says_which_settings_differ() -> None:
    values = dict.fromkeys(GROUP_SETTINGS, "x")
    mine = fingerprint(values)
    theirs = fingerprint({**values, "max_streams": "8", "input_key": "cams/a/image"})
    assert differing(mine, mine) == []
    assert differing(mine, theirs) == ["input_key", "max_streams"]


def test_live_streams_keep_each_name_once_and_within_the_bound() -> None:
    live = LiveStreams(bound=2)
    assert live.add("x/a/b/cam/c", "a/b/c")
    assert not live.add("x/a/b/cam/c", "a/b/c")
    with pytest.raises(AnnouncementError, match="name_collision"):
        live.add("x/a/cam/b/c", "a/b/c")
    assert live.add("x/d", "d")
    with pytest.raises(AnnouncementError, match="too_many_announced"):
        live.add("x/e", "e")
    assert live.remove("x/d") and not live.remove("x/d")
    assert live.keys() == {"x/a/b/cam/c"}


def test_unique_short_lived_streams_leave_nothing_behind() -> None:
    live = LiveStreams()
    for i in range(20_000):
        live.add(f"cams/{i}/image", str(i))
        live.remove(f"cams/{i}/image")
    assert len(live) == 0
    assert live.keys() == frozenset()


@given(stream_names, member_names, st.integers(min_value=1, max_value=8))
def test_capacity_bounds_what_each_member_holds(
    streams: list[str], members: list[str], capacity: int
) -> None:
    holder = assign(streams, members, capacity=capacity)
    loads = Counter(holder.values())
    assert all(load <= capacity for load in loads.values())
    assert len(holder) == min(len(streams), capacity * len(members))
    if len(streams) <= capacity * len(members):
        assert holder == assign(streams, members)
