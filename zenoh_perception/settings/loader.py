"""Settings from the documented file and the flags: every flat key read through the table of
:mod:`~.table`, each value checked for its kind before the sections are made."""

from __future__ import annotations

import argparse
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import MISSING
from enum import Enum
from pathlib import Path
from typing import Any

from zenoh_perception.errors import SettingsError
from zenoh_perception.files import check_nesting, read_text_file
from zenoh_perception.settings.bounds import MAX_SETTINGS_FILE_BYTES
from zenoh_perception.settings.model import Settings
from zenoh_perception.settings.table import BOUNDS, FLAT, FlatKey


def settings_from_mapping(
    values: Mapping[str, object], base: Settings | None = None, *, source: str = "settings"
) -> Settings:
    """``base`` (default: the defaults) with ``values`` (flat keys) applied; unknown keys are
    errors."""
    return (base if base is not None else Settings()).updated(values, source=source)


def _read_settings_file(path: Path) -> dict[str, Any]:
    """The TOML table of ``path``: a regular UTF-8 file of at most MAX_SETTINGS_FILE_BYTES,
    nested at most MAX_NESTING levels (tomllib recurses per level)."""
    text = read_text_file(path, "settings file", MAX_SETTINGS_FILE_BYTES)
    check_nesting(text, f"settings file {path}")
    try:
        return tomllib.loads(text)
    except ValueError as err:  # TOMLDecodeError, or an integer past Python's digit limit
        msg = f"cannot read settings file {path}: {err}"
        raise SettingsError(msg) from err
    except RecursionError as err:  # tomllib recurses once per nested array or table
        msg = f"cannot read settings file {path}: nested too deeply"
        raise SettingsError(msg) from err


def load_settings(path: Path | None, overrides: Mapping[str, object] | None = None) -> Settings:
    """Defaults, then the TOML file at ``path`` (if any), then ``overrides``.

    Raises:
        SettingsError: unreadable file (missing, not a regular file, over 1 MiB, not UTF-8),
            bad TOML, unknown key, wrong type or invalid value.

    """
    settings = Settings()
    if path is not None:
        data = _read_settings_file(path)
        settings = settings_from_mapping(data, settings, source=str(path))
    if overrides:
        settings = settings_from_mapping(overrides, settings, source="flags")
    return settings


def _help(name: str, key: FlatKey) -> str:
    f = key.field
    default = f.default if f.default is not MISSING else None
    if isinstance(default, Enum):
        default = default.value  # as the file writes it
    bound = BOUNDS.get(name)
    limits = f"; {bound.describe()}" if bound is not None else ""
    return f"{f.metadata.get('help', '')}{limits} (default: {default!r})"


def add_settings_arguments(parser: argparse.ArgumentParser) -> None:
    """One flag per setting (``--tag-key``...), defaulting to 'not given'."""
    group = parser.add_argument_group("perception settings (override the --settings file)")
    group.add_argument(
        "-s",
        "--settings",
        type=Path,
        default=None,
        metavar="FILE",
        help="TOML settings file (see config/perception.toml)",
    )
    for name, key in FLAT.items():
        flag = "--" + name.replace("_", "-")
        kind, help_text = key.kind, _help(name, key)
        if kind is bool:
            group.add_argument(
                flag,
                dest=name,
                action=argparse.BooleanOptionalAction,
                default=None,
                help=help_text,
            )
        elif kind is list:  # given several times: a list
            group.add_argument(
                flag,
                dest=name,
                action="append",
                default=None,
                metavar=name.upper(),
                help=help_text,
            )
        else:  # a mode is read as text, checked as the file's is
            group.add_argument(
                flag,
                dest=name,
                type=kind if kind in (int, float) else str,
                default=None,
                metavar=name.upper(),
                help=help_text,
            )


def settings_from_args(args: argparse.Namespace) -> Settings:
    """Settings from ``--settings FILE`` plus every per-setting flag that was given."""
    overrides = {
        name: getattr(args, name) for name in FLAT if getattr(args, name, None) is not None
    }
    path: Path | None = getattr(args, "settings", None)
    return load_settings(path, overrides)


def setting_names() -> Sequence[str]:
    return list(FLAT)
