"""``bridge-config``: the real command writes the bridge file for the settings and flags it
is given, and refuses keys the bridge cannot route (exit 2, naming the setting)."""

from __future__ import annotations

from pathlib import Path

import json5

from tests.helpers import run_cli


def test_several_cameras_by_pattern_in_a_namespace(tmp_path: Path) -> None:
    out = tmp_path / "bridge.json5"
    result = run_cli(
        "bridge-config",
        "--input-key", "rover1/cams/*/image",
        "--compressed-input-key", "rover1/cams/*/image/compressed",
        "--tag-key", "rover1/cams/{stream}/tag",
        "--record-key", "rover1/cams/{stream}/perception/tags",
        "--debug-image-key", "rover1/cams/{stream}/debug",
        "--detections-key", "",
        "--tf-key", "rover1/tf",
        "--namespace", "/rover1",
        "--domain", "7",
        "-o", str(out),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    plugin = json5.loads(out.read_text(encoding="utf-8"))["plugins"]["ros2dds"]
    assert (plugin["namespace"], plugin["domain"]) == ("/rover1", 7)
    assert plugin["allow"]["publishers"] == [
        "/cams/[^/]+/image",
        "/cams/[^/]+/image/compressed",
    ]
    assert plugin["allow"]["subscribers"] == ["/cams/[^/]+/tag", "/cams/[^/]+/debug", "/tf"]


def test_a_key_outside_the_namespace_exits_2_naming_it() -> None:
    result = run_cli("bridge-config", "--namespace", "/rover1")
    assert result.returncode == 2
    assert "input_key = 'zed/left/image' does not start with the bridge's namespace" in (
        result.stderr
    )


def test_an_rmw_zenoh_service_needs_no_bridge() -> None:
    result = run_cli("bridge-config", "--ros-transport", "rmw_zenoh")
    assert result.returncode == 2
    assert "ros_transport" in result.stderr
