"""``view``'s parts that need no Zenoh: finding out whether a window can be opened, and the
atomic save."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import pytest

from zenoh_perception.cli.view import ViewError, display_available, save_atomically

#: OpenCV's build says which GUI backend it has; opencv-python-headless has none.
HAS_GUI = re.search(r"GUI:\s+NONE", cv2.getBuildInformation()) is None


def test_no_display_variable_means_no_window(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert display_available() is False


@pytest.mark.skipif(HAS_GUI, reason="opening a window needs a real display here")
def test_a_display_with_a_headless_opencv_means_no_window(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DISPLAY", ":99")
    assert display_available() is False  # cv2.namedWindow raised, and was caught


def test_save_replaces_the_file_whole(tmp_path: Path) -> None:
    path = tmp_path / "latest.jpg"
    save_atomically(path, b"first")
    save_atomically(path, b"second")
    assert path.read_bytes() == b"second"
    assert [p.name for p in tmp_path.iterdir()] == ["latest.jpg"]


def test_save_into_a_missing_folder_names_the_path(tmp_path: Path) -> None:
    path = tmp_path / "missing" / "x.jpg"
    with pytest.raises(ViewError, match=re.escape(str(path))):
        save_atomically(path, b"x")
