"""wire/stream_keys.py: stream names from the chunks a wildcard input matched, output keys."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.wire.stream_keys import STREAM, has_wildcard, stream_key, stream_name


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
    assert stream_key(template, name) == key


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
    output = stream_key("out/{stream}/tag", name)
    assert zenoh.KeyExpr(output) == zenoh.KeyExpr(f"out/{name}/tag")
    other = stream_key("out/{stream}/tag", name + "x")
    assert other != output
