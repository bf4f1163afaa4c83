"""JSON from the network, decoded within bounds: size, nesting, and no NaN or Infinity.

Python's ``json`` recurses once per nesting level (200,000 brackets are a RecursionError) and
accepts ``NaN`` and ``Infinity``, which are not JSON and which it would print back as such.
The size is checked before anything is decoded and the nesting before ``json`` parses.
"""

from __future__ import annotations

import json
from typing import Any, Final

from zenoh_perception.errors import JsonPayloadError
from zenoh_perception.files import nesting_depth

#: Largest JSON payload accepted by default (a service's status is a few KiB).
MAX_JSON_BYTES: Final = 1 << 20
#: Deepest nesting of arrays and objects accepted by default (a status nests 3 levels).
MAX_JSON_DEPTH: Final = 32


def _refuse_constant(name: str) -> Any:
    raise JsonPayloadError("non_finite", f"{name} is not JSON")


def loads_bounded(
    data: bytes, *, max_bytes: int = MAX_JSON_BYTES, max_depth: int = MAX_JSON_DEPTH
) -> Any:
    """The JSON value ``data`` holds.

    Raises:
        JsonPayloadError: ``data`` is over ``max_bytes`` (``too_large``), is not UTF-8 JSON
            (``not_json``), nests deeper than ``max_depth`` (``too_deep``) or holds NaN or
            Infinity (``non_finite``).

    """
    if len(data) > max_bytes:
        msg = f"{len(data)} bytes, over the {max_bytes} accepted"
        raise JsonPayloadError("too_large", msg)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise JsonPayloadError("not_json", f"not UTF-8: {err}") from err
    if (depth := nesting_depth(text)) > max_depth:
        msg = f"nested {depth} levels deep, over the {max_depth} accepted"
        raise JsonPayloadError("too_deep", msg)
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except ValueError as err:
        raise JsonPayloadError("not_json", str(err)) from err
