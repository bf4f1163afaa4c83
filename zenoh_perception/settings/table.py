"""The table of flat keys: each key of ``config/perception.toml`` (and flag) to its section and
field, derived from the section classes. The loader, the flags, the status reply and the
generic checks (bounds, text) read settings through it; everything else by typed path."""

from __future__ import annotations

import typing
from collections.abc import Iterator, Mapping
from dataclasses import Field, dataclass, fields
from typing import Any, Final

from zenoh_perception.errors import SettingsError
from zenoh_perception.settings.bounds import Bound
from zenoh_perception.settings.sections import SECTIONS, TagSizes
from zenoh_perception.wire.stream_keys import Keys


@dataclass(frozen=True, slots=True)
class FlatKey:
    """Where a flat key lives: its section (the attribute of ``Settings``) and field."""

    section: str
    field: Field[Any]
    #: How values are read: ``list`` (a key or a list of keys), ``tuple`` (tag sizes), an enum
    #: (its values' text), or ``str``, ``int``, ``float``, ``bool``.
    kind: type

    @property
    def is_keys(self) -> bool:
        return self.kind is list

    @property
    def bound(self) -> Bound | None:
        bound = self.field.metadata.get("bound")
        return bound if isinstance(bound, Bound) else None


def _kind(hint: object) -> type:
    if hint == Keys:
        return list  # one key, or several
    if hint == TagSizes:
        return tuple
    if isinstance(hint, type) and issubclass(hint, str | int | float | bool):
        return hint  # an enum among them
    msg = f"no kind of setting for {hint!r}"
    raise TypeError(msg)


def _flat_table() -> dict[str, FlatKey]:
    table: dict[str, FlatKey] = {}
    for section, cls in SECTIONS.items():
        hints = typing.get_type_hints(cls)
        for f in fields(cls):
            if f.name in table:
                msg = f"{f.name} is in sections {table[f.name].section} and {section}"
                raise AssertionError(msg)
            table[f.name] = FlatKey(section, f, _kind(hints[f.name]))
    return table


#: Every flat key, in the order of the sections, to its place.
FLAT: Final[Mapping[str, FlatKey]] = _flat_table()
#: The bounds of every numeric setting (``config/perception.toml`` states them too).
BOUNDS: Final[Mapping[str, Bound]] = {
    name: key.bound for name, key in FLAT.items() if key.bound is not None
}


def section_items(section: object) -> Iterator[tuple[str, Any]]:
    """Each flat key of ``section`` (an instance of a section class) with its value."""
    for f in fields(section):  # type: ignore[arg-type]
        yield f.name, getattr(section, f.name)


def check_bound(name: str, value: float) -> None:
    """Raise :class:`SettingsError` unless ``value`` is within the bounds of setting ``name``."""
    bound = BOUNDS[name]
    if not bound.admits(value):
        msg = f"{name} must be in {bound.describe()}, not {value!r}"
        raise SettingsError(msg)
