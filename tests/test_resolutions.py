"""The named camera resolutions: one table for the scene camera, the demo and the bench."""

from __future__ import annotations

from zenoh_perception.cli.main import build_parser
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception_bench.scene import CameraModel


def test_the_zed_resolutions() -> None:
    assert RESOLUTIONS == {
        "VGA": (640, 480),
        "HD720": (1280, 720),
        "HD1080": (1920, 1080),
        "HD2K": (2208, 1242),
    }


def test_named_cameras_and_the_demo_use_the_table() -> None:
    for name, size in RESOLUTIONS.items():
        assert CameraModel.named(name).size == size
        assert build_parser().parse_args(["demo", "--resolution", name]).resolution == name
    assert build_parser().parse_args(["demo"]).resolution == "VGA"
