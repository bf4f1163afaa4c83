"""Settings: defaults, the documented TOML file, flag overrides and validation."""

from __future__ import annotations

import argparse
import json
import os
import re
import tomllib
from collections import Counter
from dataclasses import fields
from enum import Enum
from pathlib import Path

import pytest

from tests.helpers import REPO
from zenoh_perception.cli import main as cli
from zenoh_perception.errors import SettingsError
from zenoh_perception.service.zenoh_args import add_zenoh_arguments
from zenoh_perception.settings import (
    BOUNDS,
    FLAT,
    MAX_SETTINGS_FILE_BYTES,
    SECTIONS,
    DetectorKind,
    DetectorProcess,
    Metric,
    Policy,
    RosTransportKind,
    Settings,
    add_settings_arguments,
    check_ros_package,
    load_settings,
    setting_names,
    settings_from_args,
    settings_from_mapping,
)
from zenoh_perception.wire.stream_keys import stream_name

CONFIG = REPO / "config" / "perception.toml"


def test_documented_file_lists_every_setting_with_its_default() -> None:
    with CONFIG.open("rb") as stream:
        data = tomllib.load(stream)
    assert set(data) == set(FLAT)
    assert load_settings(CONFIG) == Settings()
    text = CONFIG.read_text()
    for name in FLAT:  # every key has a comment somewhere above it
        assert re.search(rf"#[^\n]*\n(#[^\n]*\n)*{name} =|{name} =", text)


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
    assert settings.outputs.tag_key == "from_flag"
    assert settings.selection.policy == "center"
    assert settings.debug.debug_image is False
    assert settings.selection.max_range_m == 4.0
    assert settings.selection.tag_sizes == ((3, 0.25), (7, 0.1))
    assert settings.selection.tag_size_for(7) == 0.1 and settings.selection.tag_size_for(1) == 0.0


def test_every_setting_has_a_flag() -> None:
    parser = argparse.ArgumentParser()
    add_settings_arguments(parser)
    flags = {opt for action in parser._actions for opt in action.option_strings}
    for name in FLAT:
        assert "--" + name.replace("_", "-") in flags


@pytest.mark.parametrize(
    "values",
    [
        {"policy": "random"},
        {"metric": "loudness"},
        {"detector": "magic"},
        {"detector_process": "sometimes"},
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
        {
            "metric": "distance",
            "camera_fx": 500,
            "camera_fy": 500,
            "camera_cx": 319.5,
            "camera_cy": 239.5,
            "tag_size_m": 0.2,
        }
    )
    assert settings.selection.has_intrinsics and settings.selection.metric == "distance"


def test_bad_toml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("policy = \n")
    with pytest.raises(SettingsError, match=r"bad\.toml"):
        load_settings(path)
    with pytest.raises(SettingsError, match=r"missing\.toml"):
        load_settings(tmp_path / "missing.toml")


# -- bounds of every number -----------------------------------------------------------------


def _numeric_settings() -> list[str]:
    return [name for name, key in FLAT.items() if key.kind in (int, float)]


def test_every_number_has_bounds_documented_above_its_key() -> None:
    text = CONFIG.read_text()
    lines = text.splitlines()
    for name in _numeric_settings():
        assert name in BOUNDS, name
        index = next(i for i, line in enumerate(lines) if line.startswith(f"{name} ="))
        comments: list[str] = []
        for line in reversed(lines[:index]):
            if not line.startswith("#"):
                break
            comments.append(line)
        assert BOUNDS[name].describe() in " ".join(comments), name


@pytest.mark.parametrize(
    ("values", "named"),
    [
        ({"opencv_threads": 4 * (os.cpu_count() or 1) + 1}, "opencv_threads"),
        ({"opencv_threads": -1}, "opencv_threads"),
        ({"stats_interval_s": 0.05}, "stats_interval_s"),
        ({"stats_interval_s": 86_401}, "stats_interval_s"),
        ({"stats_interval_s": float("inf")}, "stats_interval_s"),
        ({"log_interval_s": 0}, "log_interval_s"),
        ({"log_interval_s": 100_000}, "log_interval_s"),
        ({"debug_image_max_hz": 5000}, "debug_image_max_hz"),
        ({"max_range_m": 1e9}, "max_range_m"),
        ({"tag_size_m": 1000}, "tag_size_m"),
        ({"min_tag_side_px": 1e6}, "min_tag_side_px"),
        ({"max_frame_bytes": 100}, "max_frame_bytes"),
        ({"max_frame_bytes": 2**40}, "max_frame_bytes"),
        ({"max_frame_pixels": 0}, "max_frame_pixels"),
        ({"frame_budget_ms": 0}, "frame_budget_ms"),
        ({"frame_deadline_ms": 5}, "frame_deadline_ms"),
        ({"frame_deadline_ms": -1}, "frame_deadline_ms"),
        ({"frame_deadline_ms": 600_001}, "frame_deadline_ms"),
        ({"tag_sizes": {"2147483648": 0.2}}, "tag_sizes"),
        ({"tag_sizes": {"3": 500}}, "tag_sizes"),
        ({"camera_fx": 1e9, "camera_fy": 1e9, "camera_cx": 320, "camera_cy": 240}, "camera_fx"),
        ({"camera_fx": 500, "camera_cx": 320, "camera_cy": 240}, "camera_fy"),
        ({"camera_fx": 500, "camera_fy": 500}, "camera_cx"),  # principal point left at 0
        ({"camera_fx": 500, "camera_fy": 50, "camera_cx": 320, "camera_cy": 240}, "camera_fx"),
        ({"camera_cx": 1e6}, "camera_cx"),
    ],
)
def test_numbers_out_of_bounds_are_refused_naming_the_setting(
    values: dict[str, object], named: str
) -> None:
    with pytest.raises(SettingsError, match=named):
        settings_from_mapping(values)


def test_numbers_at_their_bounds_and_zero_where_it_means_off_are_accepted() -> None:
    settings = settings_from_mapping(
        {
            "opencv_threads": 4 * (os.cpu_count() or 1),
            "stats_interval_s": 0,
            "log_interval_s": 86_400,
            "max_frame_bytes": 4 << 30,
            "max_frame_pixels": 16384 * 16384,
            "frame_budget_ms": 0.1,
            "frame_deadline_ms": 0,
            "camera_fx": 100_000,
            "camera_fy": 30_000,
            "camera_cx": 0.5,
            "camera_cy": 16383,
        }
    )
    assert settings.logs.stats_interval_s == 0.0
    assert settings.limits.frame_deadline_ms == 0.0


# -- keys --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("values", "named"),
    [
        ({"tag_key": "perception/*"}, "tag_key"),
        ({"record_key": "perception/**"}, "record_key"),
        ({"debug_image_key": "perception/$*debug"}, "debug_image_key"),
        ({"status_key": "perception/*/status"}, "status_key"),
        ({"liveliness_key": "perception/*"}, "liveliness_key"),
        ({"tag_key": "a//b"}, "tag_key"),  # empty chunk
        ({"input_key": "zed/**/**"}, "input_key"),  # not canonical: no auto-canonisation
        ({"input_key": "zed/left?"}, "input_key"),
        ({"record_key": "zed/left/image"}, "record_key"),  # the input itself
        ({"input_key": "**"}, "tag_key"),  # every output is an input
        ({"input_key": "perception/*"}, "record_key"),
        ({"camera_info_key": "perception/**"}, "record_key"),
        ({"camera_info_key": "zed/**"}, "camera_info_key"),
        ({"tag_key": "perception/tags"}, "record_key"),  # two outputs on one key
    ],
)
def test_keys_are_validated_naming_the_setting(values: dict[str, object], named: str) -> None:
    with pytest.raises(SettingsError, match=named):
        settings_from_mapping(values)


#: Output keys of a stream each, as a wildcard input needs.
STREAM_OUTPUTS = {
    "tag_key": "cams/{stream}/tag",
    "record_key": "cams/{stream}/perception/tags",
    "debug_image_key": "cams/{stream}/debug",
    "detections_key": "cams/{stream}/detections",
}


def test_a_wildcard_input_needs_stream_outputs_and_a_wildcard_or_no_other_input() -> None:
    with pytest.raises(SettingsError, match="record_key"):
        settings_from_mapping(
            {
                **STREAM_OUTPUTS,
                "record_key": "p/tags",
                "input_key": "c/*",
                "compressed_input_key": "",
            }
        )
    concrete = {"compressed_input_key": "zed/left/image/compressed"}  # set beside a pattern
    with pytest.raises(SettingsError, match="compressed_input_key"):
        settings_from_mapping({**STREAM_OUTPUTS, "input_key": "cams/*/image", **concrete})
    both = settings_from_mapping(
        {
            **STREAM_OUTPUTS,
            "input_key": "cams/*/image",
            "compressed_input_key": "cams/*/image/compressed",
        }
    )
    assert both.outputs.tf_key == "tf"  # one TF topic for every stream


@pytest.mark.parametrize(
    ("input_key", "compressed"),
    [
        ("zed/left/image", "zed/left/image/compressed"),
        ("rover/*/image", "rover/*/image/compressed"),
        (
            ["rover/front/image", "rover/rear/image"],
            ("rover/front/image/compressed", "rover/rear/image/compressed"),
        ),
        ("rover/**", ""),  # already matches its compressed frames
        ("", "zed/left/image/compressed"),  # compressed frames only: the ZED's
    ],
)
def test_the_compressed_input_follows_the_camera_keys_unless_set(
    input_key: str | list[str], compressed: str | tuple[str, ...]
) -> None:
    outputs = STREAM_OUTPUTS if input_key not in ("zed/left/image", "") else {}
    values = {**outputs, "input_key": input_key}
    assert settings_from_mapping(values).inputs.compressed_input_key == compressed
    # from the documented file too, then a flag: the file's default follows the flag's camera
    from_file = load_settings(CONFIG, values)
    assert from_file.inputs.compressed_input_key == compressed
    if input_key:
        off = settings_from_mapping({**values, "compressed_input_key": ""})
        assert off.inputs.compressed_input_key == ""


def test_the_compressed_input_follows_in_both_transports() -> None:
    values = {
        "ros_transport": "rmw_zenoh",
        "input_key": ["front/image", "rear/image"],
        "tag_key": "{stream}/tag",
        "record_key": "{stream}/perception/tags",
        "debug_image_key": "{stream}/debug/image/compressed",
        "detections_key": "{stream}/perception/detections",
    }
    settings = settings_from_mapping(values)
    assert settings.inputs.compressed_input_key == (
        "front/image/compressed",
        "rear/image/compressed",
    )


def test_input_keys_may_be_key_expressions() -> None:
    settings = settings_from_mapping(
        {
            "input_key": "rover$*/zed/*/image",
            "compressed_input_key": "",
            "camera_info_key": "rover$*/zed/*/camera_info",
            **STREAM_OUTPUTS,
        }
    )
    assert settings.inputs.input_key == "rover$*/zed/*/image"


@pytest.mark.parametrize("name", ["Mrover", "mr-over", "a__b", "_ab", "1abc", "x", "ab_", ""])
def test_ros_package_must_be_a_ros_package_name(name: str) -> None:
    with pytest.raises(SettingsError, match="ros_package"):
        settings_from_mapping({"ros_package": name})


def test_ros_package_names_that_ros_accepts() -> None:
    for name in ("mrover", "my_msgs", "nav2_msgs", "a1"):
        assert check_ros_package(name) == name


# -- the settings file ---------------------------------------------------------------------------


def test_a_settings_file_over_1_mib_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "huge.toml"
    line = "# " + "x" * 1021 + "\n"
    path.write_text(line * (MAX_SETTINGS_FILE_BYTES // len(line) + 1))
    with pytest.raises(SettingsError, match=r"huge\.toml is larger than 1048576 bytes"):
        load_settings(path)


def test_a_settings_file_that_is_not_utf8_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes('# caf\u00e9\ntag_key = "tag"\n'.encode("latin-1"))
    with pytest.raises(SettingsError, match=r"latin1\.toml is not UTF-8"):
        load_settings(path)


def test_a_settings_path_that_is_not_a_regular_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SettingsError, match="not a regular file"):
        load_settings(tmp_path)


def test_bad_values_in_the_file_name_the_file_and_the_setting(tmp_path: Path) -> None:
    path = tmp_path / "bad_value.toml"
    path.write_text("stats_interval_s = 0.01\n")
    with pytest.raises(SettingsError, match=r"bad_value\.toml: stats_interval_s must be in"):
        load_settings(path)


def test_a_dictionary_is_kept_in_opencvs_spelling() -> None:
    assert (
        Settings.from_flat(dictionary="dict_apriltag_36h11").detection.dictionary
        == "DICT_APRILTAG_36h11"
    )
    assert (
        settings_from_mapping({"dictionary": "dict_4x4_50"}).detection.dictionary == "DICT_4X4_50"
    )


def test_an_unknown_setting_names_the_closest_one() -> None:
    with pytest.raises(SettingsError, match=r"dictionnary \(did you mean dictionary\?\)"):
        settings_from_mapping({"dictionnary": "DICT_4X4_50"})
    with pytest.raises(SettingsError, match=r"unknown setting\(s\) zzz$"):
        settings_from_mapping({"zzz": 1})


def test_a_deeply_nested_settings_file_is_one_error(tmp_path: Path) -> None:
    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * 100_000)
    with pytest.raises(SettingsError, match=r"deep\.toml is nested 100000 levels deep"):
        load_settings(path)


def test_several_dictionaries_are_one_setting_in_opencvs_spelling() -> None:
    settings = settings_from_mapping({"dictionary": "dict_4x4_50,DICT_APRILTAG_16h5, DICT_4X4_50"})
    assert settings.detection.dictionary == "DICT_4X4_50, DICT_APRILTAG_16h5"
    with pytest.raises(SettingsError, match="unknown ArUco dictionary"):
        settings_from_mapping({"dictionary": "DICT_4X4_50,"})


@pytest.mark.parametrize(
    ("values", "named"),
    [
        ({"ros_transport": "dds"}, "ros_transport"),
        ({"ros_domain_id": 233}, "ros_domain_id"),
        ({"ros_domain_id": -1}, "ros_domain_id"),
        ({"ros_node_name": "zenoh-perception"}, "ros_node_name"),
        ({"ros_node_name": ""}, "ros_node_name"),
        ({"ros_namespace": "rover"}, "ros_namespace"),
        ({"ros_namespace": "/rover/"}, "ros_namespace"),
        ({"ros_transport": "rmw_zenoh", "input_key": "zed/*/image"}, "input_key"),
        ({"ros_transport": "rmw_zenoh", "tag_key": "perception/1tag"}, "tag_key"),
        ({"ros_transport": "rmw_zenoh", "camera_info_key": "zed/**"}, "camera_info_key"),
    ],
)
def test_ros_graph_settings_are_validated_naming_the_setting(
    values: dict[str, object], named: str
) -> None:
    with pytest.raises(SettingsError, match=named):
        settings_from_mapping(values)


@pytest.mark.parametrize(
    ("values", "named"),
    [
        # would take compressed frames
        (
            {"input_key": "zed/left/**", "compressed_input_key": "zed/left/x"},
            "compressed_input_key",
        ),
        ({"compressed_input_key": "zed/left/image"}, "compressed_input_key"),
        ({"detections_key": "perception/tags"}, "detections_key"),  # shares the record's key
        ({"tf_key": "zed/left/image/compressed"}, "tf_key"),  # an input
        ({"tf_key": "tf/*"}, "tf_key"),
        ({"tf_prefix": "/tag_"}, "tf_prefix"),
        ({"tf_prefix": "tag "}, "tf_prefix"),
    ],
)
def test_the_ros_output_and_compressed_input_keys_are_validated(
    values: dict[str, object], named: str
) -> None:
    with pytest.raises(SettingsError, match=named):
        settings_from_mapping(values)


def test_ros_graph_settings_that_ros_accepts() -> None:
    settings = settings_from_mapping(
        {
            "ros_transport": "rmw_zenoh",
            "ros_domain_id": 232,
            "ros_node_name": "perception_2",
            "ros_namespace": "/rover/left",
        }
    )
    assert settings.ros.ros_transport == "rmw_zenoh"
    # wildcards stay fine for the bridge, whose keys are no ROS names
    wildcard = settings_from_mapping(
        {"input_key": "zed/*/image", "compressed_input_key": "", **STREAM_OUTPUTS}
    )
    assert wildcard.inputs.input_key == "zed/*/image"


def test_one_input_may_be_off_but_not_both() -> None:
    assert settings_from_mapping({"input_key": ""}).inputs.compressed_input_key
    with pytest.raises(SettingsError, match="input_key and compressed_input_key"):
        settings_from_mapping({"input_key": "", "compressed_input_key": ""})


def test_empty_compressed_detections_and_tf_keys_turn_them_off() -> None:
    settings = settings_from_mapping(
        {
            **STREAM_OUTPUTS,
            "compressed_input_key": "",
            "detections_key": "",
            "tf_key": "",
            "input_key": "zed/**",
        }
    )
    assert (
        settings.inputs.compressed_input_key,
        settings.outputs.detections_key,
        settings.outputs.tf_key,
    ) == ("", "", "")


def test_verify_is_on_by_default_and_off_by_flag_or_file(tmp_path: Path) -> None:
    assert Settings().detection.verify is True
    assert settings_from_args(_parse("--no-verify")).detection.verify is False
    assert settings_from_args(_parse("--verify")).detection.verify is True
    path = tmp_path / "s.toml"
    path.write_text("verify = false\n")
    assert load_settings(path).detection.verify is False
    path.write_text('verify = "no"\n')
    with pytest.raises(SettingsError, match="verify"):
        load_settings(path)


# -- share_group ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["a/b", "*", "-x", ".x", "x" * 65, "@g", "a b", "$*"])
def test_share_group_is_one_plain_key_chunk(name: str) -> None:
    with pytest.raises(SettingsError, match="share_group"):
        settings_from_mapping({"share_group": name})


def test_share_group_names_that_are_accepted() -> None:
    for name in ("rover", "base_station", "fleet-2.a", "0", "x" * 64):
        assert settings_from_mapping({"share_group": name}).group.share_group == name
    assert Settings().group.share_group == ""  # every stream, as before


def test_share_group_works_with_either_transport() -> None:
    # the group learns rmw_zenoh cameras from their publishers' liveliness tokens
    settings = settings_from_mapping({"share_group": "rover", "ros_transport": "rmw_zenoh"})
    assert settings.group.share_group == "rover"


def test_an_input_that_gives_two_cameras_one_stream_name_is_refused() -> None:
    """``x/**/cam/**`` names ``x/a/b/cam/c`` and ``x/a/cam/b/c`` both ``a/b/c``: one mailbox
    and one detector state for two cameras. Refused, naming two such keys."""
    outputs = {k: f"out/{{stream}}/{k}" for k in ("tag_key", "record_key", "detections_key")}
    with pytest.raises(SettingsError) as caught:
        settings_from_mapping(
            {
                "input_key": "x/**/cam/**",
                "compressed_input_key": "",
                "debug_image_key": "out/{stream}/debug",
                **outputs,
            }
        )
    assert "input_key = 'x/**/cam/**' gives two cameras one stream name" in str(caught.value)
    first, second = re.findall(r"\('([^']+)' and '([^']+)'", str(caught.value))[0]
    assert stream_name("x/**/cam/**", first) == stream_name("x/**/cam/**", second)
    assert first != second


# -- several cameras as a list of keys ---------------------------------------------------------

#: Output keys of a stream each, beside a list of cameras (ROS topic names too).
LIST_OUTPUTS = {
    "tag_key": "{stream}/tag",
    "record_key": "{stream}/perception/tags",
    "debug_image_key": "{stream}/perception/debug/image/compressed",
    "detections_key": "{stream}/perception/detections",
}


def test_a_list_of_cameras_from_the_file_and_from_repeated_flags(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    lines = [f'{k} = "{v}"' for k, v in LIST_OUTPUTS.items()]
    path.write_text(
        "\n".join(
            [
                *lines,
                'input_key = ["front/image", "rear/image"]',
                'compressed_input_key = ["front/image/compressed", "rear/image/compressed"]',
                'camera_info_key = ["front/camera_info", "rear/camera_info"]',
            ]
        )
        + "\n"
    )
    from_file = load_settings(path)
    assert from_file.inputs.input_key == ("front/image", "rear/image")
    assert from_file.inputs.camera_info_entries == ("front/camera_info", "rear/camera_info")
    assert from_file.inputs.several
    assert from_file.as_dict()["input_key"] == ("front/image", "rear/image")
    # each flag given again adds a key; given, the flags replace the file's list
    args = _parse(
        "--settings",
        str(path),
        "--input-key",
        "front/image",
        "--input-key",
        "side/image",
        "--input-key",
        "rear/image",
        "--compressed-input-key",
        "",
    )
    from_flags = settings_from_args(args)
    assert from_flags.inputs.input_key == ("front/image", "side/image", "rear/image")
    assert from_flags.inputs.compressed_input_key == ""


def test_a_list_of_one_key_is_that_key() -> None:
    args = _parse("--input-key", "cams/front/image")
    settings = settings_from_args(args)
    assert settings.inputs.input_key == "cams/front/image"
    assert not settings.inputs.several
    assert settings_from_mapping({"input_key": ["zed/left/image"]}) == Settings()
    assert Settings.from_flat(input_key=("zed/left/image",)) == Settings()


@pytest.mark.parametrize(
    ("values", "named"),
    [
        ({"input_key": []}, "input_key"),
        ({"input_key": ["a/image", ""]}, "input_key"),
        ({"input_key": ["a/image", 3]}, "input_key"),
        ({"input_key": "a/image", "camera_info_key": ["a/info", "b/info"]}, "camera_info_key"),
        # the same camera twice, or a key two entries both match
        ({"input_key": ["a/image", "a/image"]}, "input_key"),
        ({"input_key": ["cams/*/image", "cams/front/image"]}, "input_key"),
        ({"input_key": ["cams/**", "cams/front/image/x"]}, "input_key"),
        # an entry that is all chunks the others share names no stream
        ({"input_key": ["cams/image", "cams/image/left"]}, "input_key"),
        ({"input_key": ["a/image", "b/image"], "compressed_input_key": "zed"}, "compressed_input"),
        ({"input_key": ["a/image", "perception/tags"]}, "record_key"),
        ({"input_key": ["a/image", "b/image"], "compressed_input_key": ["b/**"]}, "input_key"),
        ({"input_key": ["a/image", "b/im\x01age"]}, "input_key"),
        ({"input_key": ["a/image", "{stream}/image"]}, "input_key"),
        ({"input_key": ["a/image", "b//image"]}, "input_key"),
    ],
)
def test_a_bad_list_of_cameras_is_refused_naming_the_setting(
    values: dict[str, object], named: str
) -> None:
    with pytest.raises(SettingsError, match=named) as raised:
        settings_from_mapping({**LIST_OUTPUTS, "compressed_input_key": "", **values})
    # one line, but for the keys several cameras need: those are listed, one per line
    assert "\n" not in str(raised.value) or "would start" in str(raised.value)


@pytest.mark.parametrize("output", ["tag_key", "record_key", "debug_image_key", "detections_key"])
def test_a_list_of_cameras_needs_stream_outputs(output: str) -> None:
    values = {**LIST_OUTPUTS, output: "shared/key", "compressed_input_key": ""}
    named = rf"input_key = .*lists several keys(.|\n)*{output} = .*must hold '{{stream}}'"
    with pytest.raises(SettingsError, match=named):
        settings_from_mapping({**values, "input_key": ["a/image", "b/image"]})


def test_a_list_of_cameras_beside_patterns_and_on_a_ros_graph() -> None:
    mixed = settings_from_mapping(
        {
            **LIST_OUTPUTS,
            "input_key": ["front/image", "rear/image"],
            "compressed_input_key": "*/image/compressed",
            "camera_info_key": "*/camera_info",
        }
    )
    assert mixed.inputs.several and mixed.outputs.tf_key == "tf"
    ros = settings_from_mapping(
        {
            **LIST_OUTPUTS,
            "ros_transport": "rmw_zenoh",
            "input_key": ["front/image", "rear/image"],
            "compressed_input_key": "",
        }
    )
    assert ros.inputs.input_entries == ("front/image", "rear/image")
    with pytest.raises(SettingsError, match="input_key = 'rear/im-age'"):
        settings_from_mapping(
            {
                **LIST_OUTPUTS,
                "ros_transport": "rmw_zenoh",
                "input_key": ["front/image", "rear/im-age"],
                "compressed_input_key": "",
            }
        )


def test_a_list_of_more_cameras_than_max_streams_is_refused() -> None:
    values = {**LIST_OUTPUTS, "compressed_input_key": "", "input_key": ["a/i", "b/i", "c/i"]}
    assert settings_from_mapping({**values, "max_streams": 3}).inputs.several
    with pytest.raises(SettingsError, match="input_key lists 3 keys, more than max_streams = 2"):
        settings_from_mapping({**values, "max_streams": 2})


# -- sections and modes ---------------------------------------------------------------------

MODES = {
    "detector": DetectorKind,
    "detector_process": DetectorProcess,
    "ros_transport": RosTransportKind,
    "policy": Policy,
    "metric": Metric,
}
_INTRINSICS = {"camera_fx": 500.0, "camera_fy": 500.0, "camera_cx": 319.5, "camera_cy": 239.5}
#: A value other than the default for every key: (as written in the file, as kept, what it
#: needs beside it).
OTHER_VALUES: dict[str, tuple[object, object, dict[str, object]]] = {
    "input_key": ("cam/image", "cam/image", {}),
    "compressed_input_key": ("cam/compressed", "cam/compressed", {}),
    "camera_info_key": ("zed/left/camera_info", "zed/left/camera_info", {}),
    "max_streams": (8, 8, {}),
    "stream_idle_s": (30.0, 30.0, {}),
    "tag_key": ("out/tag", "out/tag", {}),
    "record_key": ("out/tags", "out/tags", {}),
    "debug_image_key": ("out/debug", "out/debug", {}),
    "detections_key": ("", "", {}),
    "tf_key": ("out/tf", "out/tf", {}),
    "tf_prefix": ("marker_", "marker_", {}),
    "status_key": ("out/status", "out/status", {}),
    "liveliness_key": ("out/alive", "out/alive", {}),
    "share_group": ("rover", "rover", {}),
    "ros_package": ("rover_msgs", "rover_msgs", {}),
    "ros_transport": ("rmw_zenoh", RosTransportKind.RMW_ZENOH, {}),
    "bridge_announce": (False, False, {}),
    "ros_domain_id": (7, 7, {}),
    "ros_node_name": ("perception", "perception", {}),
    "ros_namespace": ("/rover", "/rover", {}),
    "dictionary": ("DICT_5X5_100", "DICT_5X5_100", {}),
    "detector": ("tracking", DetectorKind.TRACKING, {}),
    "full_scan_period": (8, 8, {}),
    "second_look": (False, False, {}),
    "opencv_threads": (1, 1, {}),
    "min_tag_side_px": (12.5, 12.5, {}),
    "verify": (False, False, {}),
    "confirm_frames": (2, 2, {}),
    "refine_corners": (False, False, {}),
    "max_frame_bytes": (1 << 20, 1 << 20, {}),
    "max_frame_pixels": (1920 * 1080, 1920 * 1080, {}),
    "frame_budget_ms": (50.5, 50.5, {}),
    "frame_deadline_ms": (0.0, 0.0, {}),
    "detector_process": ("always", DetectorProcess.ALWAYS, {}),
    "workers": (2, 2, {}),
    "policy": ("center", Policy.CENTER, {}),
    "metric": ("distance", Metric.DISTANCE, {**_INTRINSICS, "tag_size_m": 0.2}),
    "max_range_m": (5.5, 5.5, {}),
    "tag_size_m": (0.2, 0.2, {}),
    "tag_sizes": ({"3": 0.25}, ((3, 0.25),), {}),
    "camera_fx": (500.0, 500.0, {k: v for k, v in _INTRINSICS.items() if k != "camera_fx"}),
    "camera_fy": (500.0, 500.0, {k: v for k, v in _INTRINSICS.items() if k != "camera_fy"}),
    "camera_cx": (100.5, 100.5, {}),
    "camera_cy": (100.5, 100.5, {}),
    "debug_image": (False, False, {}),
    "debug_image_max_hz": (2.5, 2.5, {}),
    "debug_jpeg_quality": (50, 50, {}),
    "stats_interval_s": (0.0, 0.0, {}),
    "log_interval_s": (1.5, 1.5, {}),
    "no_tag_hint_s": (0.0, 0.0, {}),
}


def test_every_flat_key_is_a_field_of_exactly_one_section() -> None:
    owners = Counter(f.name for cls in SECTIONS.values() for f in fields(cls))
    assert set(owners) == set(FLAT) == set(setting_names())
    assert set(owners.values()) == {1}
    assert [f.name for f in fields(Settings)] == list(SECTIONS)
    for name, key in FLAT.items():
        assert name in {f.name for f in fields(SECTIONS[key.section])}
        assert isinstance(getattr(Settings(), key.section), SECTIONS[key.section])


def _toml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {v!r}" for k, v in value.items()) + " }"
    return json.dumps(value) if isinstance(value, str) else repr(value)


def _flag(name: str, value: object) -> list[str]:
    flag = "--" + name.replace("_", "-")
    if isinstance(value, bool):
        return [flag if value else "--no-" + flag[2:]]
    if isinstance(value, dict):
        return [flag, ",".join(f"{k}={v}" for k, v in value.items())]
    return [flag, str(value)]


def _kept(settings: Settings, name: str) -> object:
    return getattr(getattr(settings, FLAT[name].section), name)


def test_every_key_has_another_value_here() -> None:
    assert set(OTHER_VALUES) == set(FLAT)
    for name, (_written, kept, _beside) in OTHER_VALUES.items():
        assert kept != FLAT[name].field.default, name


@pytest.mark.parametrize("name", list(OTHER_VALUES))
def test_each_key_round_trips_from_the_file_and_from_its_flag(name: str, tmp_path: Path) -> None:
    written, kept, beside = OTHER_VALUES[name]
    path = tmp_path / "s.toml"
    path.write_text("".join(f"{k} = {_toml(v)}\n" for k, v in {name: written, **beside}.items()))
    from_file = load_settings(path)
    argv = [arg for k, v in {name: written, **beside}.items() for arg in _flag(k, v)]
    from_flag = settings_from_args(_parse(*argv))
    for settings in (from_file, from_flag):
        assert _kept(settings, name) == kept
        assert type(_kept(settings, name)) is type(kept)
        # the status reply shows it as the file writes it
        shown = json.loads(json.dumps(settings.as_dict()))[name]
        assert shown == (written if not isinstance(written, tuple) else list(written))
    assert from_file == from_flag == Settings.from_flat(**{name: written, **beside})


def test_the_modes_are_the_enums_of_their_keys() -> None:
    assert {n: k.kind for n, k in FLAT.items() if issubclass(k.kind, Enum)} == MODES


@pytest.mark.parametrize(("name", "mode"), list(MODES.items()))
def test_a_mode_reads_each_documented_text(name: str, mode: type[Enum]) -> None:
    lines = CONFIG.read_text().splitlines()
    index = next(i for i, line in enumerate(lines) if line.startswith(f"{name} ="))
    documented = " ".join(lines[max(0, index - 12) : index + 1])
    for member in mode:
        assert f"{member.value}" in documented, (name, member)
        for settings in (
            Settings.from_flat(**{name: member.value, **OTHER_VALUES[name][2]}),
            settings_from_args(_parse(*_flag(name, member.value), *_beside(name))),
        ):
            assert _kept(settings, name) is member
            assert f"{_kept(settings, name)}" == member.value  # logs and status as written


def _beside(name: str) -> list[str]:
    return [arg for k, v in OTHER_VALUES[name][2].items() for arg in _flag(k, v)]


@pytest.mark.parametrize(("name", "mode"), list(MODES.items()))
@pytest.mark.parametrize("text", ["bogus", "", "OPENCV", "Closest", " area"])
def test_a_mode_refuses_any_other_text_naming_the_setting(
    name: str, mode: type[Enum], text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    choices = ", ".join(m.value for m in mode)
    expected = f"{name} must be one of {choices}, not {text!r}"
    with pytest.raises(SettingsError) as refused:
        Settings.from_flat(**{name: text})
    assert str(refused.value) == f"settings: {expected}"
    with pytest.raises(SettingsError, match=re.escape(f"flags: {expected}")):
        settings_from_args(_parse(*_flag(name, text)))
    with pytest.raises(SettingsError, match=re.escape(f"setting {name} must be str, not 5")):
        Settings.from_flat(**{name: 5})
    assert cli.main(["run", *_flag(name, text), "--no-multicast-scouting"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line == f"zenoh-perception: error: flags: {expected}"
