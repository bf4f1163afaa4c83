"""Flat keys applied to settings: each value checked for its kind (a key or a list of keys,
tag sizes, a mode's text, a number, a flag) as the file, the flags and ``Settings.from_flat``
give them."""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from enum import Enum
from typing import Final

from zenoh_perception.errors import SettingsError
from zenoh_perception.settings.sections import TagSizes, key_list
from zenoh_perception.settings.table import FLAT

#: A tag id as ``tag_sizes`` keys must write it: decimal, no sign, no leading zero or space.
_TAG_ID: Final = re.compile(r"0|[1-9][0-9]{0,9}")


def _tag_size_items(value: object) -> list[tuple[object, object]]:
    """The (id, size) pairs of a TOML table {"3" = 0.2}, a flag "3=0.2,7=0.1" or pairs."""
    items: list[tuple[object, object]] = []
    if isinstance(value, Mapping):
        return list(value.items())
    if isinstance(value, str):
        for part in filter(None, (p.strip() for p in value.split(","))):
            key, sep, size = part.partition("=")
            if not sep:
                msg = f"tag_sizes entry {part!r} is not ID=SIZE"
                raise SettingsError(msg)
            items.append((key.strip(), size.strip()))
        return items
    if isinstance(value, tuple | list):
        for pair in value:
            if not isinstance(pair, tuple | list) or len(pair) != 2:
                msg = f"tag_sizes entry {pair!r} is not an (id, size) pair"
                raise SettingsError(msg)
            items.append((pair[0], pair[1]))
        return items
    msg = f"tag_sizes must be a table of id = size, not {type(value).__name__}"
    raise SettingsError(msg)


def _parse_tag_sizes(value: object) -> TagSizes:
    """Accept a TOML table {"3" = 0.2} or a flag string "3=0.2,7=0.1"."""
    pairs: list[tuple[int, float]] = []
    seen: dict[int, object] = {}
    for raw_key, raw_size in _tag_size_items(value):
        # one spelling per id: "3", "03" and " 3" would otherwise all be id 3
        if not (isinstance(raw_key, int) and not isinstance(raw_key, bool)) and not (
            isinstance(raw_key, str) and _TAG_ID.fullmatch(raw_key)
        ):
            msg = f"tag_sizes id {raw_key!r} is not a tag id written plainly (0, 1, 2, ...)"
            raise SettingsError(msg)
        tag_id = int(raw_key)
        if tag_id in seen:
            msg = f"tag_sizes gives id {tag_id} twice ({seen[tag_id]!r} and {raw_key!r})"
            raise SettingsError(msg)
        seen[tag_id] = raw_key
        try:
            pairs.append((tag_id, float(str(raw_size))))
        except ValueError as err:
            msg = f"tag_sizes: {err}"
            raise SettingsError(msg) from err
    return tuple(sorted(pairs))


def coerce(name: str, value: object) -> object:
    """``value`` of flat key ``name`` as its section keeps it (SettingsError: not of its kind)."""
    kind = FLAT[name].kind
    if kind is tuple:
        return _parse_tag_sizes(value)
    if kind is list:
        return key_list(name, value)
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                return float(value)
            except OverflowError as err:
                msg = f"setting {name} = {str(value)[:40]}... is too large for a number"
                raise SettingsError(msg) from err
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif issubclass(kind, Enum):
        if isinstance(value, str):
            return _mode(name, kind, value)
    elif isinstance(value, str):
        return value
    msg = f"setting {name} must be {_kind_name(kind)}, not {value!r}"
    raise SettingsError(msg)


def _mode(name: str, kind: type[Enum], value: str) -> Enum:
    """The member of mode ``kind`` written ``value`` (its text, as documented)."""
    try:
        return kind(value)
    except ValueError as err:
        msg = f"{name} must be one of {', '.join(m.value for m in kind)}, not {value!r}"
        raise SettingsError(msg) from err


def _kind_name(kind: type) -> str:
    return "str" if issubclass(kind, Enum) else kind.__name__


def check_known(values: Mapping[str, object], source: str) -> None:
    """Refuse a key that is no setting, naming the closest one."""
    unknown = sorted(set(values) - set(FLAT))
    if unknown:
        hints = [
            f"{name} (did you mean {close[0]}?)"
            if (close := difflib.get_close_matches(name, FLAT, n=1))
            else name
            for name in unknown
        ]
        msg = f"{source}: unknown setting(s) {', '.join(hints)}"
        raise SettingsError(msg)
