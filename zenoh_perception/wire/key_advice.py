"""What a user would write anyway about keys: the compressed input beside each camera key,
each output key of several cameras, and every key to change said in one message.

- :func:`compressed_keys`: image_transport publishes a camera's compressed frames on the
  camera's topic plus ``/compressed``; unless set, ``compressed_input_key`` is that, per entry.
- :func:`stream_example`: an output key with ``{stream}`` where a camera's name goes
  (``tag`` beside ``rover/*/image`` -> ``rover/{stream}/tag``).
- :func:`unknown_placeholders`: ``{camera}`` and the like, which nothing replaces.
- :func:`refusal`: one message naming every key to change, then the flags and the settings
  lines that would start.

Pure: no Zenoh, no logging.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from zenoh_perception.wire.stream_keys import STREAM, Keys, has_wildcard, key_entries

#: The last chunk image_transport's compressed plugin adds to a camera's topic.
COMPRESSED_SUFFIX: Final = "compressed"
#: ``compressed_input_key``'s default as written in the settings: each ``input_key`` entry
#: plus ``/compressed``.
FOLLOWS_INPUT: Final = "{input_key}/compressed"
_PLACEHOLDER: Final = re.compile(r"\{[^{}/]*\}")


def compressed_keys(input_key: Keys) -> Keys:
    """Each entry of ``input_key`` plus ``/compressed`` (``""`` when off); an entry ending
    in ``**`` already matches its compressed frames, so it gets none."""
    entries = tuple(
        f"{entry}/{COMPRESSED_SUFFIX}"
        for entry in key_entries(input_key)
        if entry.rsplit("/", 1)[-1] != "**"
    )
    if not entries:
        return ""
    return entries[0] if len(entries) == 1 else entries


def unknown_placeholders(value: str) -> list[str]:
    """The ``{...}`` in ``value`` that are not :data:`STREAM`, in order."""
    return [found for found in _PLACEHOLDER.findall(value) if found != STREAM]


def _prefix(entries: Sequence[str]) -> list[str]:
    """The literal chunks every entry starts with, up to the first wildcard or difference."""
    split = [entry.split("/") for entry in entries]
    common: list[str] = []
    for chunks in zip(*split, strict=False):
        if has_wildcard(chunks[0]) or any(c != chunks[0] for c in chunks):
            break
        common.append(chunks[0])
    # a concrete single entry names no stream: its last chunk is the camera's own
    return common[:-1] if len(split) == 1 and not has_wildcard(entries[0]) else common


def stream_example(inputs: Sequence[str], value: str) -> str:
    """``value`` as a stream's output key: the chunks the inputs share before the camera's
    name, then ``{stream}``, then ``value`` (``tag`` beside ``rover/*/image``:
    ``rover/{stream}/tag``; ``rover/tag`` too)."""
    prefix, chunks = _prefix(inputs), value.split("/")
    if chunks[: len(prefix)] == prefix and len(chunks) > len(prefix):
        chunks = chunks[len(prefix) :]  # the shared chunks written already
    return "/".join([*prefix, STREAM, *chunks])


@dataclass(frozen=True, slots=True)
class Change:
    """One key to change: the setting, what it is, why not, and a value that would do."""

    name: str
    value: Keys
    why: str
    example: Keys


def _toml(value: Keys) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    return "[" + ", ".join(f'"{entry}"' for entry in value) + "]"


def _flags(name: str, value: Keys) -> str:
    flag = "--" + name.replace("_", "-")
    return " ".join(
        f"{flag} '{entry}'" for entry in ((value,) if isinstance(value, str) else value)
    )


def refusal(context: str, changes: Sequence[Change]) -> str:
    """One message: ``context`` (why the keys are held to these rules), every key to change
    with why, then the flags and the settings lines that would start."""
    lines = [f"{context}; change {len(changes)} key(s):"]
    lines += [f"  {c.name} = {_shown(c.value)}: {c.why}" for c in changes]
    lines.append("these flags beside yours would start (or these lines in the --settings file):")
    lines.append("  " + " ".join(_flags(c.name, c.example) for c in changes))
    lines += [f"  {c.name} = {_toml(c.example)}" for c in changes]
    return "\n".join(lines)


def _shown(value: Keys) -> str:
    return repr(value) if isinstance(value, str) else repr(list(value))
