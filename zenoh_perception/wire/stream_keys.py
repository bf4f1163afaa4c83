"""Streams from key expressions: which camera a concrete key names, and its output keys.

A wildcard input key (``cams/*/image``, ``rover/**/image``) matches many concrete keys; each
is a *stream*, named by the chunks the wildcards matched (``cams/front/image`` -> ``front``;
with ``**`` matching several chunks, those chunks joined by ``/``). An output key holding
:data:`STREAM` (``cams/{stream}/tag``) is that stream's key once the name is put in its place.
A concrete input key has one stream, named ``""``.

Pure: no Zenoh, no logging.
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Final

#: The placeholder of an output key that the stream's name replaces.
STREAM: Final = "{stream}"


def has_wildcard(key: str) -> bool:
    """Whether ``key`` holds a wildcard (``*``, ``**`` or ``$*``)."""
    return "*" in key


@lru_cache(maxsize=64)
def _chunk_pattern(chunk: str) -> re.Pattern[str] | None:
    """A chunk with ``$*`` in it as a regular expression (None: no partial wildcard)."""
    if "$*" not in chunk:
        return None
    return re.compile(".*".join(re.escape(part) for part in chunk.split("$*")), re.DOTALL)


def _match(pattern: tuple[str, ...], key: tuple[str, ...]) -> list[str] | None:
    """The key chunks the pattern's wildcard chunks matched, in order; None: no match."""
    if not pattern:
        return [] if not key else None
    head, rest = pattern[0], pattern[1:]
    if head == "**":
        for taken in range(len(key) + 1):
            matched = _match(rest, key[taken:])
            if matched is not None:
                return [*key[:taken], *matched]
        return None
    if not key:
        return None
    partial = _chunk_pattern(head)
    if head == "*" or (partial is not None and partial.fullmatch(key[0])):
        matched = _match(rest, key[1:])
        return None if matched is None else [key[0], *matched]
    if head != key[0]:
        return None
    return _match(rest, key[1:])


def stream_name(pattern: str, key: str) -> str | None:
    """The name of the stream ``key`` is under the key expression ``pattern``: the chunks
    its wildcards matched, joined by ``/`` (``""`` for a pattern without wildcards); None
    when ``key`` does not match ``pattern``."""
    if not has_wildcard(pattern):
        return "" if key == pattern else None
    matched = _match(tuple(pattern.split("/")), tuple(key.split("/")))
    return None if matched is None else "/".join(matched)


def stream_key(template: str, name: str) -> str:
    """``template`` with :data:`STREAM` replaced by ``name``; chunks left empty (the stream
    ``""``, or ``**`` that matched no chunk) are dropped, so the key stays valid."""
    if STREAM not in template:
        return template
    return "/".join(chunk for chunk in template.replace(STREAM, name).split("/") if chunk)
