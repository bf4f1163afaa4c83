"""JSON from the network within bounds: size, nesting, no NaN or Infinity."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.errors import JsonPayloadError
from zenoh_perception.files import nesting_depth
from zenoh_perception.wire.bounded_json import loads_bounded

_JSON = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
    max_leaves=20,
)


@given(_JSON)
def test_what_json_dumps_comes_back(value: object) -> None:
    assert loads_bounded(json.dumps(value).encode()) == value


@given(st.text())
def test_brackets_inside_strings_are_no_nesting(text: str) -> None:
    assert nesting_depth(json.dumps([text])) == 1


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"[" * 200_000 + b"]" * 200_000, "too_deep"),
        (b'{"a": NaN}', "non_finite"),
        (b"[Infinity]", "non_finite"),
        (b"[-Infinity]", "non_finite"),
        (b"<html>", "not_json"),
        (b"\xff", "not_json"),
        (b" " * (2 << 20), "too_large"),
    ],
)
def test_refused_with_a_reason(data: bytes, reason: str) -> None:
    with pytest.raises(JsonPayloadError) as caught:
        loads_bounded(data)
    assert caught.value.reason == reason
