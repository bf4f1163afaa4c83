"""What the settings derive and suggest for keys: pure functions, from the README's cases."""

from __future__ import annotations

import pytest

from zenoh_perception.wire.key_advice import (
    Change,
    compressed_keys,
    refusal,
    stream_example,
    unknown_placeholders,
)


@pytest.mark.parametrize(
    ("input_key", "expected"),
    [
        ("zed/left/image", "zed/left/image/compressed"),
        ("rover/*/image", "rover/*/image/compressed"),
        (("a/image", "b/image"), ("a/image/compressed", "b/image/compressed")),
        ("rover/**", ""),
        (("a/**", "b/image"), "b/image/compressed"),
        ("", ""),
    ],
)
def test_compressed_keys_follow_image_transport(
    input_key: str | tuple[str, ...], expected: str | tuple[str, ...]
) -> None:
    assert compressed_keys(input_key) == expected


@pytest.mark.parametrize(
    ("inputs", "value", "expected"),
    [
        (["rover/*/image"], "tag", "rover/{stream}/tag"),
        (["rover/*/image"], "rover/tag", "rover/{stream}/tag"),
        (["rover/*/image"], "perception/tags", "rover/{stream}/perception/tags"),
        (["rover/front/image", "rover/rear/image"], "tag", "rover/{stream}/tag"),
        (["*/image"], "tag", "{stream}/tag"),
        (["cams/front/image", "arm/camera/image"], "tag", "{stream}/tag"),
    ],
)
def test_each_key_gets_its_own_stream_example(inputs: list[str], value: str, expected: str) -> None:
    assert stream_example(inputs, value) == expected


def test_unknown_placeholders_are_named_and_stream_is_not() -> None:
    assert unknown_placeholders("rover/{camera}/tag") == ["{camera}"]
    assert unknown_placeholders("rover/{stream}/tag") == []
    assert unknown_placeholders("a/{}/{x}/{stream}") == ["{}", "{x}"]


def test_a_refusal_lists_every_key_then_flags_and_settings_lines() -> None:
    changes = [
        Change("tag_key", "tag", "must hold '{stream}'", "rover/{stream}/tag"),
        Change("compressed_input_key", "z/c", "one concrete key", ("a/c", "b/c")),
    ]
    lines = refusal("input_key = 'rover/*/image' has wildcards", changes).splitlines()
    assert lines[0].endswith("change 2 key(s):")
    assert lines[1:3] == [
        "  tag_key = 'tag': must hold '{stream}'",
        "  compressed_input_key = 'z/c': one concrete key",
    ]
    assert lines[4] == (
        "  --tag-key 'rover/{stream}/tag' --compressed-input-key 'a/c' --compressed-input-key 'b/c'"
    )
    assert lines[5:] == [
        '  tag_key = "rover/{stream}/tag"',
        '  compressed_input_key = ["a/c", "b/c"]',
    ]
