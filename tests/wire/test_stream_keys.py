"""wire/stream_keys.py: stream names from the chunks a wildcard input matched, output keys."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.wire.stream_keys import (
    STREAM,
    StreamNames,
    colliding_keys,
    has_wildcard,
    key_entries,
    output_key,
    stream_name,
)


@pytest.mark.parametrize(
    ("pattern", "key", "name"),
    [
        ("cams/*/image", "cams/front/image", "front"),
        ("cams/*/image", "cams/front/left/image", None),
        ("rover/**/image", "rover/zed/left/image", "zed/left"),
        ("rover/**/image", "rover/image", ""),
        ("rover/*/zed/*/image", "rover/a/zed/left/image", "a/left"),
        ("cam$*/image", "camfront/image", "camfront"),
        ("cam$*/image", "front/image", None),
        ("zed/left/image", "zed/left/image", ""),
        ("zed/left/image", "zed/right/image", None),
        ("**", "a/b", "a/b"),
    ],
)
def test_the_stream_is_named_by_what_the_wildcards_matched(
    pattern: str, key: str, name: str | None
) -> None:
    assert stream_name(pattern, key) == name
    # the name is given exactly when Zenoh says the key matches the pattern
    assert (name is not None) == zenoh.KeyExpr(pattern).intersects(zenoh.KeyExpr(key))


@pytest.mark.parametrize(
    ("template", "name", "key"),
    [
        ("cams/{stream}/tag", "front", "cams/front/tag"),
        ("cams/{stream}/tag", "zed/left", "cams/zed/left/tag"),
        ("cams/{stream}/tag", "", "cams/tag"),  # no empty chunk
        ("{stream}/tag", "front", "front/tag"),
        ("tag_{stream}", "front", "tag_front"),
        ("tag", "front", "tag"),
    ],
)
def test_an_output_key_is_the_streams_once_its_name_is_in_place(
    template: str, name: str, key: str
) -> None:
    assert output_key(template, name) == key


def test_wildcards_are_told() -> None:
    assert has_wildcard("cams/*/image") and has_wildcard("a/**") and has_wildcard("c$*")
    assert not has_wildcard("cams/front/image") and not has_wildcard(STREAM)


CHUNK = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=8)


@given(names=st.lists(CHUNK, min_size=1, max_size=4), star=st.booleans())
def test_a_name_put_in_the_input_comes_back_and_names_the_output(
    names: list[str], star: bool
) -> None:
    """For any camera name: the key a camera publishes on names that stream, and its outputs
    are a concrete key expression holding the name, distinct for distinct names."""
    pattern = "cams/*/image" if star else "rover/**/image"
    name = names[0] if star else "/".join(names)
    key = f"cams/{name}/image" if star else f"rover/{name}/image"
    assert stream_name(pattern, key) == name
    output = output_key("out/{stream}/tag", name)
    assert zenoh.KeyExpr(output) == zenoh.KeyExpr(f"out/{name}/tag")
    other = output_key("out/{stream}/tag", name + "x")
    assert other != output


# -- a list of keys ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("entries", "key", "name"),
    [
        (("cams/front/image", "cams/rear/image"), "cams/front/image", "front"),
        (("cams/front/image", "cams/rear/image"), "cams/rear/image", "rear"),
        (("front/image", "rear/image"), "rear/image", "rear"),
        (("rover/front/image", "rover/rear/zed/image"), "rover/rear/zed/image", "rear/zed"),
        # entries alike at neither end: the whole key
        (("front/image", "rear/camera"), "front/image", "front/image"),
        # a pattern entry: its matched key, less the chunks common to every entry
        (("cams/*/image", "arm/cam/image"), "cams/left/image", "cams/left"),
        (("cams/*/image", "arm/cam/image"), "arm/cam/image", "arm/cam"),
        # a wildcard chunk is never common, even where every entry has one
        (("a/*/image", "a/*/depth"), "a/x/depth", "x/depth"),
        (("cams/front/image", "cams/rear/image"), "cams/side/image", None),
        (("cams/front/image", "cams/rear/image"), "cams/front/image/x", None),
    ],
)
def test_a_list_names_a_stream_by_the_chunks_its_entries_do_not_share(
    entries: tuple[str, ...], key: str, name: str | None
) -> None:
    names = StreamNames(entries)
    assert names.name(key) == name
    assert names.several


@pytest.mark.parametrize(
    ("pattern", "key"),
    [
        ("cams/*/image", "cams/front/image"),
        ("rover/**/image", "rover/zed/left/image"),
        ("rover/*/zed/*/image", "rover/a/zed/left/image"),
        ("zed/left/image", "zed/left/image"),
        ("zed/left/image", "zed/right/image"),
    ],
)
def test_one_entry_names_its_streams_as_the_key_alone_does(pattern: str, key: str) -> None:
    assert StreamNames(pattern).name(key) == stream_name(pattern, key)
    assert StreamNames((pattern,)).name(key) == stream_name(pattern, key)
    assert StreamNames(pattern).several == has_wildcard(pattern)


def test_the_entries_of_an_input_setting() -> None:
    assert key_entries("") == ()
    assert key_entries("a/b") == ("a/b",)
    assert key_entries(("a", "b")) == ("a", "b")
    assert StreamNames(("a/image", "b/image")).entry_of("b/image") == "b/image"
    assert StreamNames(("a/*", "b/image")).entry_of("a/x") == "a/*"
    assert StreamNames(("a/*", "b/image")).entry_of("c/x") is None
    assert not StreamNames("").several


@given(names=st.lists(CHUNK, min_size=2, max_size=5, unique=True))
def test_the_cameras_of_a_list_come_back_as_their_names(names: list[str]) -> None:
    """Cameras listed as ``rover/<name>/image``: each key names its camera's stream."""
    streams = StreamNames(tuple(f"rover/{name}/image" for name in names))
    assert [streams.name(f"rover/{name}/image") for name in names] == names


@pytest.mark.parametrize("pattern", ["x/**/cam/**", "**/x/**", "a/**/b/**/c", "a/**/b/*/**"])
def test_two_double_wildcards_can_give_two_keys_one_name(pattern: str) -> None:
    pair = colliding_keys(pattern)
    assert pair is not None
    first, second = pair
    assert first != second
    assert stream_name(pattern, first) == stream_name(pattern, second) is not None


@pytest.mark.parametrize(
    "pattern", ["cams/*/image", "rover/**/image", "a/*/**", "a/**/b/*", "a/**/**", "cam$*/x"]
)
def test_one_double_wildcard_gives_every_key_its_own_name(pattern: str) -> None:
    assert colliding_keys(pattern) is None
