"""Settings: defaults, the documented TOML file, flag overrides and validation."""

from __future__ import annotations

import argparse
import re
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest

from zenoh_perception.errors import SettingsError
from zenoh_perception.settings import (
    Settings,
    add_settings_arguments,
    load_settings,
    settings_from_args,
    settings_from_mapping,
)
from zenoh_perception.zenoh_args import add_zenoh_arguments, zenoh_config_from_args

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "perception.toml"


def test_documented_file_lists_every_setting_with_its_default() -> None:
    with CONFIG.open("rb") as stream:
        data = tomllib.load(stream)
    assert set(data) == {f.name for f in fields(Settings)}
    assert load_settings(CONFIG) == Settings()
    text = CONFIG.read_text()
    for f in fields(Settings):  # every key has a comment somewhere above it
        assert re.search(rf"#[^\n]*\n(#[^\n]*\n)*{f.name} =|{f.name} =", text)


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_settings_arguments(parser)
    add_zenoh_arguments(parser)
    return parser.parse_args(list(argv))


def test_flags_override_the_file(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('tag_key = "from_file"\npolicy = "center"\ntag_sizes = { 3 = 0.2 }\n')
    args = _parse(
        "--settings",
        str(path),
        "--tag-key",
        "from_flag",
        "--no-debug-image",
        "--max-range-m",
        "4",
        "--tag-sizes",
        "7=0.1,3=0.25",
    )
    settings = settings_from_args(args)
    assert settings.tag_key == "from_flag"
    assert settings.policy == "center"
    assert settings.debug_image is False
    assert settings.max_range_m == 4.0
    assert settings.tag_sizes == ((3, 0.25), (7, 0.1))
    assert settings.tag_size_for(7) == 0.1 and settings.tag_size_for(1) == 0.0


def test_every_setting_has_a_flag() -> None:
    parser = argparse.ArgumentParser()
    add_settings_arguments(parser)
    flags = {opt for action in parser._actions for opt in action.option_strings}
    for f in fields(Settings):
        assert "--" + f.name.replace("_", "-") in flags


@pytest.mark.parametrize(
    "values",
    [
        {"policy": "random"},
        {"metric": "loudness"},
        {"detector": "magic"},
        {"dictionary": "DICT_9X9_1"},
        {"max_range_m": 0},
        {"max_range_m": float("nan")},
        {"debug_jpeg_quality": 101},
        {"full_scan_period": 0},
        {"full_scan_period": 1001},
        {"tag_key": ""},
        {"tag_sizes": {"x": 1}},
        {"tag_sizes": {"3": -1}},
        {"stats_interval_s": "often"},
        {"debug_image": 1},
        {"tag_key": 5},
        {"no_such_setting": 1},
        {"metric": "distance"},  # without intrinsics and size
    ],
)
def test_invalid_settings_are_rejected(values: dict[str, object]) -> None:
    with pytest.raises(SettingsError):
        settings_from_mapping(values)


def test_distance_metric_with_intrinsics_and_size_is_accepted() -> None:
    settings = settings_from_mapping(
        {"metric": "distance", "camera_fx": 500, "camera_fy": 500, "tag_size_m": 0.2}
    )
    assert settings.has_intrinsics and settings.metric == "distance"


def test_bad_toml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("policy = \n")
    with pytest.raises(SettingsError, match=r"bad\.toml"):
        load_settings(path)
    with pytest.raises(SettingsError, match=r"missing\.toml"):
        load_settings(tmp_path / "missing.toml")


def test_zenoh_flags_build_the_config(tmp_path: Path) -> None:
    args = _parse(
        "-m",
        "client",
        "-e",
        "tcp/127.0.0.1:7447",
        "-e",
        "tcp/127.0.0.1:7448",
        "-l",
        "tcp/127.0.0.1:0",
        "--no-multicast-scouting",
        "--cfg",
        "scouting/delay:123",
    )
    conf = zenoh_config_from_args(args)
    assert conf.get_json("mode") == '"client"'
    assert "7448" in conf.get_json("connect/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "false"
    assert conf.get_json("scouting/delay") == "123"


@pytest.mark.parametrize(
    "argv", [["--cfg", "novalue"], ["--cfg", "no/such/key:1"], ["-c", "/no/such/file.json5"]]
)
def test_bad_zenoh_flags_are_settings_errors(argv: list[str]) -> None:
    with pytest.raises(SettingsError):
        zenoh_config_from_args(_parse(*argv))
