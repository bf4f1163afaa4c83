"""The checks of the Zenoh keys among the settings: inputs (wildcards and lists allowed) and
outputs (concrete, never intersecting an input, ``{stream}`` where several cameras need it)."""

from __future__ import annotations

from typing import Final

import zenoh

from zenoh_perception.errors import SettingsError, zenoh_error_text
from zenoh_perception.settings.sections import Inputs, Outputs
from zenoh_perception.wire.key_advice import (
    Change,
    compressed_keys,
    refusal,
    stream_example,
    unknown_placeholders,
)
from zenoh_perception.wire.stream_keys import (
    STREAM,
    Keys,
    StreamNames,
    colliding_keys,
    every_output_key,
    has_wildcard,
    key_entries,
    output_key,
)

#: Outputs that may hold ``{stream}`` (and, with a wildcard input, must: but for TF).
_STREAM_KEYS: Final = ("tag_key", "record_key", "debug_image_key", "detections_key", "tf_key")

#: A setting and its value, as messages name it.
_Named = tuple[str, str]


def shown(value: Keys) -> str:
    """An input setting as written in a message: one key, or the list."""
    return repr(value) if isinstance(value, str) else repr(list(value))


def _key_expr(name: str, value: str) -> zenoh.KeyExpr:
    try:
        return zenoh.KeyExpr(value)  # as written: no auto-canonisation
    except zenoh.ZError as err:
        msg = f"{name} = {value!r} is not a valid Zenoh key expression: {zenoh_error_text(err)}"
        raise SettingsError(msg) from err


def check_key(name: str, value: str, *, concrete: bool) -> str:
    """``value`` when it is a Zenoh key expression (without wildcards when ``concrete``: a
    key published on or served), for a command's key flag named ``name``.

    Raises:
        SettingsError: empty, a control character, not a key expression, or a wildcard in a
            concrete key.

    """
    if not value or any(ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F for c in value):
        msg = f"{name} = {value!r} must be a non-empty key without control characters"
        raise SettingsError(msg)
    _key_expr(name, value)
    if concrete and ("*" in value or "$" in value):
        msg = f"{name} = {value!r} must be a concrete key (no '*', '**' or '$*')"
        raise SettingsError(msg)
    return value


def _stream_template(name: str, value: str) -> str:
    """An output key with ``{stream}`` as a concrete key (to check it), refusing it where no
    stream is."""
    if STREAM not in value:
        return value
    if name not in _STREAM_KEYS:
        msg = f"{name} = {value!r}: only {', '.join(_STREAM_KEYS)} may hold {STREAM!r}"
        raise SettingsError(msg)
    return output_key(value, "stream")


def _validate_placeholders(inputs: Inputs, outputs: Outputs) -> None:
    every = (
        *inputs.key_lists,
        *outputs.always,
        *outputs.optional,
        ("liveliness_key", outputs.liveliness_key),
    )
    unknown = [
        f"{name} = {value!r} holds {', '.join(map(repr, found))}"
        for name, keys in every
        for value in key_entries(keys)
        if (found := unknown_placeholders(value))
    ]
    if unknown:
        msg = (
            f"unknown placeholder: {'; '.join(unknown)}; the only placeholder is {STREAM!r} "
            "(each camera's name, in output keys)"
        )
        raise SettingsError(msg)


def _check_inputs(inputs: Inputs) -> list[tuple[str, str, zenoh.KeyExpr]]:
    """Each entry of each input as (setting, entry, key expression), each input checked."""
    if not inputs.input_key and not inputs.compressed_input_key:
        msg = "input_key and compressed_input_key are both empty: the service needs an input"
        raise SettingsError(msg)
    for name, value in inputs.key_lists:
        if any(STREAM in entry for entry in key_entries(value)):
            msg = f"{name} = {shown(value)}: an input holds no {STREAM!r}"
            raise SettingsError(msg)
    entries = [
        (name, entry, _key_expr(name, entry))
        for name, value in inputs.key_lists
        for entry in key_entries(value)
    ]
    for name, value in inputs.key_lists:
        _validate_key_list(name, key_entries(value))
    return entries


def _check_outputs(outputs: Outputs, published: tuple[_Named, ...]) -> dict[str, zenoh.KeyExpr]:
    """The key expression of every key the service publishes on, serves or declares (with
    ``{stream}`` as every stream's), each checked concrete."""
    expressions: dict[str, zenoh.KeyExpr] = {}
    for name, value in (*published, ("liveliness_key", outputs.liveliness_key)):
        concrete = _stream_template(name, value)
        _key_expr(name, concrete)
        if "*" in concrete:
            msg = (
                f"{name} = {value!r} must be a concrete key (no '*', '**' or '$*'): "
                "the service publishes or declares on it"
            )
            raise SettingsError(msg)
        expressions[name] = _key_expr(name, every_output_key(value))
    return expressions


def validate_keys(inputs: Inputs, outputs: Outputs) -> None:
    _validate_placeholders(inputs, outputs)
    for name, value in (*outputs.always, ("liveliness_key", outputs.liveliness_key)):
        if not value:
            msg = f"{name} must not be empty"
            raise SettingsError(msg)
    entries = _check_inputs(inputs)
    published = (*outputs.always, *((n, v) for n, v in outputs.optional if v))
    expressions = _check_outputs(outputs, published)
    for out_name, out_value in published:
        for in_name, entry, in_key in entries:
            if expressions[out_name].intersects(in_key):
                msg = (
                    f"{out_name} = {out_value!r} intersects {in_name} = "
                    f"{entry!r}: the service would receive what it sends"
                )
                raise SettingsError(msg)
    for i, (first, first_entry, first_key) in enumerate(entries):
        for second, second_entry, second_key in entries[i + 1 :]:
            if first != second and first_key.intersects(second_key):
                msg = (
                    f"{second} = {second_entry!r} intersects {first} = "
                    f"{first_entry!r}: the two inputs would be mixed"
                )
                raise SettingsError(msg)
    seen: dict[str, str] = {}
    for name, value in published:
        if value in seen:
            msg = f"{name} and {seen[value]} are both {value!r}: each output needs its own key"
            raise SettingsError(msg)
        seen[value] = name
    _validate_streams(inputs, published)


def _validate_streams(inputs: Inputs, published: tuple[_Named, ...]) -> None:
    """With several streams (a wildcard or a list), every input and output says which."""
    several = next(((n, v) for n, v in inputs.frame_inputs if StreamNames(v).several), None)
    if several is None:
        if len(inputs.camera_info_entries) > 1:
            msg = (
                f"camera_info_key = {shown(inputs.camera_info_key)} is a list while the "
                "input is one camera: give one key"
            )
            raise SettingsError(msg)
        return
    several_name, several_value = several
    why_several = "has wildcards" if isinstance(several_value, str) else "lists several keys"
    streams = f"{several_name} = {shown(several_value)} {why_several}"
    changes: list[Change] = []
    # a concrete input beside several streams would be a stream named "" among the others
    for name, value in inputs.frame_inputs:
        if value and not StreamNames(value).several:
            why = "one concrete key beside several cameras: the same wildcards, a list, or ''"
            example = compressed_keys(inputs.input_key) if name != several_name else ""
            changes.append(Change(name, value, why, example))
    # each stream answers on keys of its own; TF is one topic whose transforms each name
    # their camera's frame
    cameras = key_entries(several_value)
    for name, value in published:
        if name in _STREAM_KEYS and name != "tf_key" and STREAM not in value:
            why = f"must hold {STREAM!r}: each camera needs keys of its own"
            changes.append(Change(name, value, why, stream_example(cameras, value)))
    if changes:
        raise SettingsError(refusal(streams, changes))


def _validate_key_list(name: str, entries: tuple[str, ...]) -> None:
    """The entries of one input: no key matched by two of them, each concrete one a stream
    name of its own (the key less the chunks every entry starts and ends with)."""
    if len(entries) < 2:
        return
    twice = next((e for i, e in enumerate(entries) if e in entries[:i]), None)
    if twice is not None:
        msg = f"{name} = {shown(entries)} gives {twice!r} twice: give each camera once"
        raise SettingsError(msg)
    keys = [_key_expr(name, entry) for entry in entries]
    for i, first in enumerate(entries):
        for j in range(i + 1, len(entries)):
            if keys[i].intersects(keys[j]):
                msg = (
                    f"{name}: the entries {first!r} and {entries[j]!r} overlap (a key both "
                    "match would be two streams): give each camera once"
                )
                raise SettingsError(msg)
    names = StreamNames(entries)
    for entry in entries:
        if not has_wildcard(entry) and not names.entry_name(entry):
            msg = (
                f"{name}: the entry {entry!r} names no stream once the chunks common to "
                f"every entry are left out (streams of {shown(entries)}: the chunks where "
                "the entries differ)"
            )
            raise SettingsError(msg)


def refuse_colliding_names(inputs: Inputs) -> None:
    """No two cameras an input matches may get one stream name (one mailbox, one detector
    state for both): a pattern of two ``**`` or more that allows it is refused."""
    for setting, value in inputs.frame_inputs:
        for entry in key_entries(value):
            pair = colliding_keys(entry)
            if pair is not None:
                msg = (
                    f"{setting} = {entry!r} gives two cameras one stream name ({pair[0]!r} and "
                    f"{pair[1]!r} would be one stream): use one '**' at most, or list the "
                    "cameras"
                )
                raise SettingsError(msg)
