"""Streams from key expressions: which camera a concrete key names, and its output keys.

A wildcard input key (``cams/*/image``, ``rover/**/image``) matches many concrete keys; each
is a *stream*, named by the chunks the wildcards matched (``cams/front/image`` -> ``front``;
with ``**`` matching several chunks, those chunks joined by ``/``). An output key holding
:data:`STREAM` (``cams/{stream}/tag``) is that stream's key once the name is put in its place.
A concrete input key has one stream, named ``""``.

An input may also be a list of key expressions (:data:`Keys`, each entry concrete or a
pattern): each concrete key an entry matches is a stream, named by the key without the chunks
common to the start and the end of every entry (``cams/front/image`` and ``cams/rear/image``
-> ``front`` and ``rear``; :class:`StreamNames`). A list of one entry is that entry alone.

Pure: no Zenoh, no logging.
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Final, TypeAlias

#: An input setting: one key expression, or several (a list of two or more entries).
Keys: TypeAlias = str | tuple[str, ...]

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


def output_key(template: str, name: str) -> str:
    """``template`` with :data:`STREAM` replaced by ``name``; chunks left empty (the stream
    ``""``, or ``**`` that matched no chunk) are dropped, so the key stays valid."""
    if STREAM not in template:
        return template
    return "/".join(chunk for chunk in template.replace(STREAM, name).split("/") if chunk)


def every_output_key(template: str) -> str:
    """An output ``template`` as the key expression of every stream's output key:
    :data:`STREAM` as a whole chunk is ``**`` (a name may span chunks), inside a chunk ``$*``."""
    chunks = template.split("/")
    return "/".join("**" if c == STREAM else c.replace(STREAM, "$*") for c in chunks)


def key_entries(keys: Keys) -> tuple[str, ...]:
    """The entries of an input setting: ``()`` when off (``""``)."""
    if isinstance(keys, str):
        return (keys,) if keys else ()
    return keys


def _literal(chunk: str) -> bool:
    return "*" not in chunk


def _common_chunks(entries: tuple[tuple[str, ...], ...]) -> int:
    """How many leading chunks every entry has alike, none of them a wildcard."""
    count = 0
    for chunks in zip(*entries, strict=False):
        if not _literal(chunks[0]) or any(c != chunks[0] for c in chunks):
            break
        count += 1
    return count


class StreamNames:
    """How the concrete keys of one input (``keys``: an input setting) name their streams.

    One entry: :func:`stream_name` (the chunks its wildcards matched; ``""`` for a concrete
    key). Several: the key matched by an entry, without the chunks common to the start and
    the end of every entry (wildcard chunks are never common), so ``front/image`` and
    ``rear/image`` are the streams ``front`` and ``rear``.
    """

    def __init__(self, keys: Keys) -> None:
        self.entries = key_entries(keys)
        split = tuple(tuple(e.split("/")) for e in self.entries)
        self._head = self._tail = 0
        if len(split) > 1:
            self._head = _common_chunks(split)
            # the tail never reaches back into the head of the shortest entry
            room = min(len(chunks) for chunks in split) - self._head
            self._tail = min(room, _common_chunks(tuple(c[::-1] for c in split)))

    @property
    def several(self) -> bool:
        """Whether the input can have several streams (a pattern, or two entries or more)."""
        return len(self.entries) > 1 or any(has_wildcard(e) for e in self.entries)

    def entry_of(self, key: str) -> str | None:
        """The entry that matches the concrete ``key`` (None: none)."""
        for entry in self.entries:
            if stream_name(entry, key) is not None:
                return entry
        return None

    def name(self, key: str) -> str | None:
        """The name of the stream of the concrete ``key``; None when no entry matches it."""
        if len(self.entries) == 1:
            return stream_name(self.entries[0], key)
        if self.entry_of(key) is None:
            return None
        chunks = key.split("/")
        return "/".join(chunks[self._head : len(chunks) - self._tail])

    def entry_name(self, entry: str) -> str:
        """The name of a concrete ``entry``'s stream (with wildcards: its own pattern of names,
        the chunks left once the common ones are removed)."""
        chunks = entry.split("/")
        if len(self.entries) == 1:
            return "" if not has_wildcard(entry) else entry
        return "/".join(chunks[self._head : len(chunks) - self._tail])


def colliding_keys(pattern: str) -> tuple[str, str] | None:
    """Two concrete keys ``pattern`` matches that :func:`stream_name` gives one name (None:
    every key it matches has a name of its own).

    Only a pattern of two ``**`` or more can: with one, the number of chunks each wildcard
    took follows from the name's length. The pair is found by trying small keys: each ``**``
    as nothing, one or two chunks (the pattern's own verbatim chunks among them), each other
    wildcard chunk as one chunk.
    """
    chunks = pattern.split("/")
    if chunks.count("**") < 2:
        return None
    literals = sorted({c for c in chunks if not has_wildcard(c)})
    fills = ["", "a", "a/b", *literals]
    fills += [*(f"a/{c}" for c in literals), *(f"{c}/a" for c in literals)]
    keys = [""]
    for chunk in chunks:
        if chunk == "**":
            options = fills
        elif has_wildcard(chunk):
            options = [chunk.replace("$*", "a").replace("*", "a")]
        else:
            options = [chunk]
        keys = [f"{k}/{o}" if k and o else k or o for k in keys for o in options][:4096]
    seen: dict[str, str] = {}
    for key in keys:
        name = stream_name(pattern, key) if key else None
        if name is None:
            continue
        first = seen.setdefault(name, key)
        if first != key:
            return first, key
    return None
