"""``zenoh-perception probe``: the dictionary of unknown pictures, through the real CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from tests.helpers import run_cli
from zenoh_perception.cli.probe import FAMILIES, READ_WITH, smallest_dictionary
from zenoh_perception.detect.types import DICTIONARIES
from zenoh_perception_bench.scene import render_markers

W, H = 640, 480


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _video(path: Path, frames: list[npt.NDArray[np.uint8]]) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (W, H))
    assert writer.isOpened()
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[:, :, :3]))
    writer.release()
    return path


def test_an_unknown_video_gets_its_family_ids_and_the_flag(tmp_path: Path) -> None:
    frames = [
        render_markers(W, H, [(23, _square(80 + 10 * i, 90, 140))], dictionary="DICT_APRILTAG_16h5")
        for i in range(12)
    ] + [render_markers(W, H, [])] * 3
    video = _video(tmp_path / "drive.avi", frames)
    result = run_cli("probe", str(video))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == f"{video}: video, 15 of 15 frames read"
    assert lines[1].split() == [
        *["DICT_APRILTAG_16h5", "12", "tags,", "ids", "23", "in", "12", "of", "15", "frames,"],
        *lines[1].split()[-2:],
    ]
    assert lines[-1] == "  -> zenoh-perception run --dictionary DICT_APRILTAG_16h5"


def test_the_smallest_dictionary_holding_every_id_is_proposed(tmp_path: Path) -> None:
    image = render_markers(
        W, H, [(3, _square(40, 40, 150)), (77, _square(300, 200, 150))], dictionary="DICT_5X5_100"
    )
    path = tmp_path / "board.png"
    cv2.imwrite(str(path), image)
    result = run_cli("probe", "--json", str(path))
    assert result.returncode == 0, result.stderr
    (answer,) = [json.loads(line) for line in result.stdout.splitlines()]
    assert answer["dictionary"] == "DICT_5X5_100"  # ids 3 and 77: DICT_5X5_50 cannot hold 77
    assert answer["found"][0]["ids"] == {"3": 1, "77": 1}
    assert answer["frames_read"] == 1 and answer["mirrored_only"] is None


def test_several_families_in_view_are_proposed_together(tmp_path: Path) -> None:
    left = render_markers(W, H, [(7, _square(40, 60, 160)), (8, _square(40, 280, 160))])
    right = render_markers(
        W,
        H,
        [(23, _square(380, 60, 160)), (5, _square(380, 280, 160))],
        dictionary="DICT_APRILTAG_36h11",
    )
    path = tmp_path / "mixed.png"
    cv2.imwrite(str(path), np.minimum(left, right))
    result = run_cli("probe", str(path))
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == (
        "  -> zenoh-perception run --dictionary 'DICT_4X4_50,DICT_APRILTAG_36h11'"
    )


def test_a_mirrored_picture_is_named_as_such(tmp_path: Path) -> None:
    image = render_markers(W, H, [(11, _square(200, 120, 200))], dictionary="DICT_6X6_250")
    path = tmp_path / "mirrored.png"
    cv2.imwrite(str(path), cv2.flip(image, 1))
    result = run_cli("probe", str(path))
    assert result.returncode == 1
    assert "found only on the mirrored picture (DICT_6X6_50)" in result.stdout


def test_a_picture_without_markers_exits_1_with_a_hint(tmp_path: Path) -> None:
    path = tmp_path / "empty.png"
    cv2.imwrite(str(path), render_markers(W, H, []))
    result = run_cli("probe", str(path))
    assert result.returncode == 1
    assert "no marker of any OpenCV dictionary found" in result.stdout


def test_a_path_that_cannot_be_read_is_one_line_and_exit_2(tmp_path: Path) -> None:
    result = run_cli("probe", str(tmp_path / "nothing.mp4"))
    assert result.returncode == 2
    assert result.stderr.strip().startswith("zenoh-perception: error: no such file")


def test_every_dictionary_belongs_to_one_family_read_by_its_largest() -> None:
    members = [name for _family, sizes in FAMILIES for name, _size in sizes]
    assert sorted(members) == sorted(DICTIONARIES)
    for dictionary in READ_WITH:
        size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)).bytesList.shape[0]
        assert dict(s for _f, sizes in FAMILIES for s in sizes)[dictionary] == size


@pytest.mark.parametrize(
    ("ids", "expected"),
    [
        ([0, 49], "DICT_4X4_50"),
        ([50], "DICT_4X4_100"),
        ([999], "DICT_4X4_1000"),
        ([], "DICT_4X4_50"),
    ],
)
def test_smallest_dictionary(ids: list[int], expected: str) -> None:
    assert smallest_dictionary("DICT_4X4_1000", ids) == expected
