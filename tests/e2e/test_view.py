"""``zenoh-perception view`` end to end: the real CLI, headless (no DISPLAY, OpenCV without a
GUI), saving the latest debug image that an in-process Zenoh peer publishes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.helpers import OutputLines, open_session, run_cli, running_cli
from tests.helpers import wait_for_subscriber as matched
from zenoh_perception.wire.debug_image import encode_compressed_image

KEY = "perception/debug/image/compressed"


@pytest.fixture(autouse=True)
def _headless(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def _image(width: int, height: int, bgr: tuple[int, int, int]) -> bytes:
    picture = np.full((height, width, 3), bgr, np.uint8)
    return bytes(encode_compressed_image(picture, quality=90, stamp_ns=1, frame_id="cam"))


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path))
    assert image is not None, f"{path} is not an image"
    return image


def _saved(line: str) -> tuple[int, int]:
    width, height = line.split()[2].split("x")
    return int(width), int(height)


def test_view_saves_the_latest_debug_image_and_skips_garbage(tmp_path: Path, endpoint: str) -> None:
    out = tmp_path / "out.jpg"
    with open_session(listen=[endpoint]) as service:
        publisher = service.declare_publisher(KEY)
        args = ("view", "-e", endpoint, "--no-multicast-scouting", "--save", str(out))
        with running_cli(*args, "--every", "0.2") as proc:
            lines = OutputLines(proc)
            matched(publisher, timeout=30)
            publisher.put(_image(320, 240, (0, 0, 255)))
            assert _saved(lines.wait_for("saved", timeout=30)) == (320, 240)
            red = _read(out)
            assert red.shape == (240, 320, 3)
            assert red[120, 160, 2] > 200 and red[120, 160, 0] < 50
            publisher.put(b"\x00\x01\x00\x00 not a CompressedImage")
            lines.wait_for("skipped", timeout=30)
            publisher.put(_image(160, 120, (255, 0, 0)))
            assert _saved(lines.wait_for("saved", timeout=30)) == (160, 120)
            blue = _read(out)
            assert blue.shape == (120, 160, 3) and blue[60, 80, 0] > 200
            assert not list(tmp_path.glob(".*.tmp"))  # written beside, then renamed
            assert proc.poll() is None
    assert proc.returncode == 0


def test_view_exits_after_count_saves(tmp_path: Path, endpoint: str) -> None:
    out = tmp_path / "one.jpg"
    with open_session(listen=[endpoint]) as service:
        publisher = service.declare_publisher(KEY)
        args = ("view", "-e", endpoint, "--no-multicast-scouting", "--save", str(out))
        with running_cli(*args, "--count", "1", "--timeout", "60") as proc:
            matched(publisher, timeout=30)
            publisher.put(_image(64, 48, (0, 255, 0)))
            proc.wait(timeout=30)
    assert proc.returncode == 0
    assert _read(out).shape == (48, 64, 3)


def test_view_without_a_display_or_save_is_one_line_and_exit_2() -> None:
    result = run_cli("view", "--no-multicast-scouting", "--timeout", "5")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--save" in lines[0]


def test_view_that_cannot_write_its_file_is_one_line_and_exit_2(
    tmp_path: Path, endpoint: str
) -> None:
    with open_session(listen=[endpoint]) as service:
        publisher = service.declare_publisher(KEY)
        missing = tmp_path / "no" / "such" / "dir.jpg"
        args = ("view", "-e", endpoint, "--no-multicast-scouting", "--save", str(missing))
        with running_cli(*args, "--timeout", "60") as proc:
            matched(publisher, timeout=30)
            publisher.put(_image(64, 48, (0, 255, 0)))
            proc.wait(timeout=30)
            assert proc.stdout is not None
            output = proc.stdout.read().strip().splitlines()
    assert proc.returncode == 2
    assert [line for line in output if "error" in line] == [output[-1]]
    assert str(missing) in output[-1]
    assert "--save" in output[-1]


def test_view_with_nothing_arriving_exits_1_naming_the_key(tmp_path: Path) -> None:
    out = tmp_path / "never.jpg"
    args = ("--no-multicast-scouting", "--save", str(out), "--timeout", "0.5")
    result = run_cli("view", *args, "--debug-image-key", "rover/{stream}/debug", timeout=60)
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert "'rover/**/debug'" in line and "--stream" in line
    assert not out.exists()


def test_view_stream_watches_one_camera_of_runs_stream_keys(tmp_path: Path, endpoint: str) -> None:
    out = tmp_path / "front.jpg"
    template = "rover/{stream}/perception/debug/image/compressed"
    with open_session(listen=[endpoint]) as service:
        front = service.declare_publisher(template.replace("{stream}", "front"))
        rear = service.declare_publisher(template.replace("{stream}", "rear"))
        args = ("view", "-e", endpoint, "--no-multicast-scouting", "--save", str(out))
        with running_cli(*args, "--debug-image-key", template, "--stream", "front") as proc:
            lines = OutputLines(proc)
            matched(front, timeout=30)
            rear.put(_image(32, 24, (0, 0, 255)))  # another camera's: not watched
            front.put(_image(64, 48, (0, 255, 0)))
            assert _saved(lines.wait_for("saved", timeout=30)) == (64, 48)
            status: object = rear.matching_status  # a MatchingStatus, whatever the stub says
            assert not getattr(status, "matching", status)


def test_view_stream_beside_a_key_without_the_placeholder_is_refused() -> None:
    result = run_cli("view", "--stream", "front", "--save", "x.jpg", timeout=60)
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "{stream}" in line and "--stream 'front'" in line
