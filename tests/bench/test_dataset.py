"""``bench --dataset``: labelled stills, sequences and videos, scored for OpenCV's default and
the service's detector side by side, OpenCV's best setting beside them (made-up items: the real
corpus is not in CI)."""

from __future__ import annotations

import copy
import gc
import json
import os
import re
import signal
import subprocess
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import pytest

from tests.bench.conftest import H, W, labelled, square
from tests.helpers import cli_command
from zenoh_perception.cli import main as cli
from zenoh_perception.settings import Settings
from zenoh_perception_bench import dataset
from zenoh_perception_bench.dataset import evaluate, nothing_found_hint
from zenoh_perception_bench.footage import frames
from zenoh_perception_bench.goals import dataset_goals
from zenoh_perception_bench.manifest import (
    DICTIONARY_PLACEHOLDER,
    MANIFEST_MAX_BYTES,
    DatasetError,
    Item,
    load_manifest,
)
from zenoh_perception_bench.plot import OPENCV_COLOUR, SERVICE_COLOUR
from zenoh_perception_bench.runners import BEST, SHOWN, rotation
from zenoh_perception_bench.scene import render_markers
from zenoh_perception_bench.scoring import BUCKETS, size_bucket


def test_every_item_is_scored_for_both_detectors(corpus: Path) -> None:
    items = load_manifest(corpus / "manifest.json")
    report = evaluate(items, corpus / "data", Settings())
    rows = {(r["name"], r["dictionary"]): r for r in report["items"]}
    two = rows["two", "DICT_4X4_50"]
    assert two["opencv"]["found"] == two["service"]["found"] == 2
    assert two["service"]["labelled"] == 2
    assert (two["camera"], two["size"]) == ("webcam", [640, 480])
    unknown = rows["unknown", "DICT_4X4_50"]
    assert (unknown["service"]["found"], unknown["service"]["unverified"]) == (1, 1)
    assert unknown["service"]["false_ids"] == 0
    assert rows["five", "DICT_5X5_100"]["service"]["found"] == 1
    # the negative is read in every dictionary the manifest uses
    assert {d for n, d in rows if n == "n-empty"} == {"DICT_4X4_50", "DICT_5X5_100"}
    assert rows["n-empty", "DICT_4X4_50"]["service"]["false_ids"] == 1
    assert rows["n-empty", "DICT_4X4_50"]["service"]["false_examples"] == {"1": 1}
    walk = rows["walk", "DICT_4X4_50"]
    assert walk["service"]["frames"] == 6
    assert walk["service"]["found"] == walk["opencv"]["found"] == 6  # id-frames
    clip = rows["clip", "DICT_4X4_50"]
    assert clip["service"]["frames"] == 8
    assert clip["service"]["found"] == clip["opencv"]["found"] == 8
    groups = report["groups"]
    assert set(groups) == {"stills", "videos", "negatives", *(f"stills {d}" for _, d in rows)}
    assert groups["stills"]["service"]["found"] == 4
    assert groups["stills DICT_5X5_100"]["service"]["found"] == 1
    assert groups["videos"]["service"]["found"] == 14
    assert groups["stills"]["service"]["buckets"][size_bucket(100.0)] == 2  # 100, 120 px
    settings = Settings()
    assert report["settings"] == {
        "detector": settings.detection.detector,
        "full_scan_period": settings.detection.full_scan_period,
        "max_frame_pixels": settings.limits.max_frame_pixels,
    }
    # the negative's false id fails that goal; every other goal passes
    failed = [g["goal"] for g in report["goals"] if not g["pass"]]
    assert failed == ["negatives: false ids (service)"]


def test_opencv_s_best_setting_is_scored_beside_them_and_not_judged(corpus: Path) -> None:
    items = load_manifest(corpus / "manifest.json")
    report = evaluate(items, corpus / "data", Settings())
    rows = {(r["name"], r["dictionary"]): r for r in report["items"]}
    for row in report["items"]:
        assert set(SHOWN) <= set(row)
        assert row[BEST]["frames"] == row["opencv"]["frames"] > 0, row["name"]
        assert row[BEST]["mean_ms"] > 0.0
    assert rows["two", "DICT_4X4_50"][BEST]["found"] == 2
    assert rows["clip", "DICT_4X4_50"][BEST]["found"] == 8
    # the negative's unlabelled marker: a false id for the best setting too
    assert rows["n-empty", "DICT_4X4_50"][BEST]["false_ids"] == 1
    for pooled in (*report["groups"].values(), *report["dictionaries"].values(), report["all"]):
        assert set(pooled) == set(SHOWN)
    assert report["groups"]["stills"][BEST]["found"] == 4
    assert report["groups"]["videos"][BEST]["found"] == 14
    assert report["all"][BEST]["frames"] == report["all"]["opencv"]["frames"]
    # shown, not judged: the goals do not move when the best setting finds nothing at all
    blind = copy.deepcopy({k: v for k, v in report.items() if k != "goals"})
    for pooled in (*blind["groups"].values(), blind["all"], *blind["items"]):
        pooled[BEST].update(found=0, false_ids=99, found_ids={})
    assert dataset_goals(blind) == report["goals"]


class _Recorder:
    """A runner that finds nothing and says when it ran."""

    def __init__(self, name: str, calls: list[str]) -> None:
        self.name, self.calls = name, calls

    def run(self, image: Any) -> tuple[list[Any], float]:
        self.calls.append(self.name)
        return [], 1.0


def test_every_frame_goes_to_each_detector_in_rotating_order(
    corpus: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[str] = []

    def recorders(dictionary: str, settings: Settings, *, best: bool = False) -> dict[str, Any]:
        assert best  # the dataset bench always runs OpenCV's best setting
        return {who: _Recorder(who, calls) for who in SHOWN}

    monkeypatch.setattr(dataset, "pair", recorders)
    items = [i for i in load_manifest(corpus / "manifest.json") if i.name == "walk"]
    evaluate(items, corpus / "data", Settings())
    frames = [calls[k : k + len(SHOWN)] for k in range(0, len(calls), len(SHOWN))]
    assert frames == [rotation(SHOWN, index) for index in range(6)]


def test_each_still_gets_detectors_of_its_own_in_rotating_order(
    corpus: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[str] = []
    made: list[str] = []

    def recorders(dictionary: str, settings: Settings, *, best: bool = False) -> dict[str, Any]:
        made.append(dictionary)
        return {who: _Recorder(who, calls) for who in SHOWN}

    monkeypatch.setattr(dataset, "pair", recorders)
    items = [i for i in load_manifest(corpus / "manifest.json") if i.kind == "image"]
    evaluate(items, corpus / "data", Settings())
    # two, unknown, five, and the negative in both of the manifest's dictionaries
    assert made == ["DICT_4X4_50", "DICT_4X4_50", "DICT_5X5_100", "DICT_4X4_50", "DICT_5X5_100"]
    reads = [calls[k : k + len(SHOWN)] for k in range(0, len(calls), len(SHOWN))]
    assert reads == [rotation(SHOWN, index) for index in range(5)]


def test_a_still_is_read_alike_whatever_came_before(tmp_path: Path) -> None:
    # a 10 px marker only the second look reads; were the stills one stream, the look would
    # be taken on its first picture only, and the marker after a picture without one missed
    data = tmp_path / "data"
    data.mkdir()
    scene = np.clip(120.0 + np.random.default_rng(0).normal(0.0, 3.0, (H, W)), 0, 255)
    cv2.imwrite(str(data / "bare.png"), scene.astype(np.uint8))
    printed = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), 7, 60
    )
    printed = cv2.copyMakeBorder(printed, *(20,) * 4, cv2.BORDER_CONSTANT, value=255)
    scene[200:217, 300:317] = cv2.resize(printed, (17, 17), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(data / "tagged.png"), scene.astype(np.uint8))
    bare = Item("bare", "image", "DICT_4X4_50", {})
    tagged = Item("tagged", "image", "DICT_4X4_50", {7: 1})
    found = []
    for order in ([tagged, bare], [bare, tagged]):
        report = evaluate(order, data, Settings())
        row = next(r for r in report["items"] if r["name"] == "tagged")
        assert row["opencv"]["found"] == 0
        found.append(row["service"]["found"])
    assert found == [1, 1]


def test_a_video_is_read_up_to_max_frames(corpus: Path) -> None:
    items = [i for i in load_manifest(corpus / "manifest.json") if i.name == "clip"]
    report = evaluate(items, corpus / "data", Settings(), max_video_frames=3)
    assert report["items"][0]["service"]["frames"] == 3
    assert report["max_video_frames"] == 3


def test_frames_are_bgra_and_a_missing_file_is_an_error(corpus: Path, tmp_path: Path) -> None:
    (walk,) = [i for i in load_manifest(corpus / "manifest.json") if i.name == "walk"]
    images = list(frames(walk, corpus / "data", max_frames=4))
    assert len(images) == 4
    assert images[0].shape == (480, 640, 4)
    with pytest.raises(DatasetError, match="no frames"):
        list(frames(walk, tmp_path, max_frames=4))
    still = Item("two", "image", "DICT_4X4_50", {3: 1})
    with pytest.raises(DatasetError, match="no file"):
        list(frames(still, tmp_path, max_frames=1))


def test_a_mirrored_item_is_flipped_back_before_it_is_read(tmp_path: Path) -> None:
    # a camera whose software stores frames mirrored: its markers read as no id until flipped
    shown = render_markers(W, H, [(3, square(200, 150, 160))])
    cv2.imwrite(str(tmp_path / "flip.png"), cv2.flip(cv2.cvtColor(shown, cv2.COLOR_BGRA2BGR), 1))
    found = {}
    for mirrored in (False, True):
        (item,) = load_manifest_from(
            {"items": [labelled("flip", "image", {"3": 1}, mirrored=mirrored)]}, tmp_path
        )
        row = evaluate([item], tmp_path, Settings())["items"][0]
        found[mirrored] = (row["opencv"]["found"], row["service"]["found"])
    assert found == {False: (0, 0), True: (1, 1)}


def load_manifest_from(data: dict[str, Any], folder: Path) -> list[Item]:
    path = folder / "m.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return load_manifest(path)


def test_an_item_is_read_with_its_labels(tmp_path: Path) -> None:
    raw = labelled("x", "video", {"1": 2}, unknown_markers=1, unsure=True, conditions=["dark"])
    (item,) = load_manifest_from({"items": [raw]}, tmp_path)
    assert item == Item(
        "x", "video", "DICT_4X4_50", {1: 2}, unknown_markers=1, unsure=True, conditions=("dark",)
    )
    assert not item.negative
    assert Item("n", "image", "DICT_4X4_50", {}).negative
    raw = labelled("y", "sequence", {"1": 1, "4": 1}, in_view={"1": [[0, 2], [7, 9]]})
    (item,) = load_manifest_from({"items": [raw]}, tmp_path)
    assert item.in_view == {1: ((0, 2), (7, 9))}
    assert item.frame(5).markers == {4: 1} and item.frame(5).out_of_view == {1}


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"items": [labelled("a", "photo", {})]}, "item 0 (a): field kind: must be one of"),
        (
            {"items": [{**labelled("a", "image", {}), "dictionary": "DICT_9X9"}]},
            "item 0 (a): field dictionary: unknown ArUco dictionary 'DICT_9X9'",
        ),
        ({"items": [labelled("a", "image", {"x": 1})]}, "item 0 (a): field markers: 'x' is not"),
        ({"items": [labelled("a", "image", {"1": 0})]}, "item 0 (a): field markers 1: must be"),
        ({"items": [labelled("a", "image", {"50": 1})]}, "id 50 is not in DICT_4X4_50"),
        (
            {"items": [{**labelled("a", "image", {}), "markers": [["1", 1]]}]},
            "item 0 (a): field markers: must be",
        ),
        ({"items": [labelled("a", "image", {}), labelled("a", "image", {})]}, "used twice"),
        ({"items": [labelled("../a", "image", {})]}, "item 0: field name: must be a plain"),
        ({"items": ["a"]}, "item 0: must be a table"),
        ({"items": [{"name": "a"}]}, "item 0 (a): field kind: required"),
        ({"items": [{}]}, "item 0: field name: required"),
        (
            {"items": [labelled("a", "image", {}, mirrored="yes")]},
            "item 0 (a): field mirrored: must be true or false",
        ),
        (
            {"items": [labelled("a", "image", {}, unknown_markers=2.5)]},
            "item 0 (a): field unknown_markers: must be a whole number",
        ),
        (
            {"items": [labelled("a", "image", {}, conditions="dark")]},
            "item 0 (a): field conditions: must be a list",
        ),
        (
            {"items": [labelled("a", "video", {"1": 1}, in_view={"2": [[0, 3]]})]},
            "item 0 (a): field in_view: '2' is not one of the item's markers",
        ),
        (
            {"items": [labelled("a", "video", {"1": 1}, in_view={"1": [[5, 3]]})]},
            "item 0 (a): field in_view: id 1: a span ends before it begins",
        ),
        (
            {"items": [labelled("a", "video", {"1": 1}, in_view={"1": [5]})]},
            "item 0 (a): field in_view: id 1: must be [[first, last], ...]",
        ),
        (
            {"items": [labelled("a", "image", {"1": 1}, in_view={"1": [[0, 0]]})]},
            "item 0 (a): field in_view: only a video or a sequence",
        ),
        ({"items": []}, "no items"),
        ({"format": 2, "items": [labelled("a", "image", {})]}, "field format"),
        ({"things": []}, "expected"),
    ],
)
def test_malformed_manifests_are_refused_naming_the_item_and_field(
    data: dict[str, Any], message: str, tmp_path: Path
) -> None:
    with pytest.raises(DatasetError, match=re.escape(message)):
        load_manifest_from(data, tmp_path)


def test_cli_exit_codes_follow_the_goals(corpus: Path, tmp_path: Path) -> None:
    manifest = corpus / "manifest.json"
    positives = json.loads(manifest.read_text(encoding="utf-8"))
    positives["items"] = [i for i in positives["items"] if i["name"] != "n-empty"]
    clean = tmp_path / "positives.json"
    clean.write_text(json.dumps(positives), encoding="utf-8")
    data = ["--data", str(corpus / "data")]
    out = tmp_path / "report.json"
    assert cli.main(["bench", "--dataset", str(clean), *data, "--json", str(out)]) == 0
    report = json.loads(out.read_text(encoding="utf-8"))
    assert set(report) == {
        "settings",
        "max_video_frames",
        "items",
        "groups",
        "dictionaries",
        "all",
        "refused",
        "goals",
    }
    assert report["goals"] and all(g["pass"] for g in report["goals"])
    assert {i["name"] for i in report["items"]} == {i["name"] for i in positives["items"]}
    # settings that drop every tag: the service finds less than OpenCV, the bench says so
    blind = tmp_path / "blind.toml"
    blind.write_text("min_tag_side_px = 1000\n", encoding="utf-8")
    out = tmp_path / "blind.json"
    argv = ["bench", "--dataset", str(clean), *data, "--settings", str(blind)]
    assert cli.main([*argv, "--json", str(out)]) == 1
    failed = [g for g in json.loads(out.read_text(encoding="utf-8"))["goals"] if not g["pass"]]
    assert any(g["goal"] == "stills: found >= OpenCV default" and g["value"] == 0 for g in failed)
    # a missing file is an error naming the item, exit 2
    assert cli.main(["bench", "--dataset", str(clean), "--data", str(tmp_path)]) == 2


def test_videos_go_end_to_end_through_service_processes_and_the_floor(corpus: Path) -> None:
    items = [i for i in load_manifest(corpus / "manifest.json") if i.name == "walk"]
    report = evaluate(items, corpus / "data", Settings(), e2e=True, shm=False)
    (row,) = report["items"]
    e2e = row["e2e"]
    assert set(e2e) == {"opencv", "tracking", "floor", "opencv_detection", "camera"}
    assert e2e["camera"]["shm"] is False
    for name in ("opencv", "tracking", "floor"):
        assert e2e[name]["records"] == 6  # every frame answered, in lockstep
    assert e2e["opencv"]["found"] == e2e["tracking"]["found"] == row["opencv"]["found"] == 6
    assert e2e["floor"]["found"] == 0  # the floor detects nothing: it only answers
    names = [g["goal"] for g in report["goals"]]
    assert "video walk: found by the service process >= OpenCV default" in names
    assert any(n.startswith("videos: service (detector=opencv) mean e2e - floor") for n in names)


def test_sigterm_during_the_bench_unwinds_through_its_finally_blocks(
    corpus: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Python's default SIGTERM would end the bench on the spot and leave its service
    # processes running: while the items are evaluated, SIGTERM must raise SystemExit
    handlers: list[object] = []

    def evaluating(*_args: object, **_kwargs: object) -> dict[str, Any]:
        handlers.append(signal.getsignal(signal.SIGTERM))
        raise SystemExit(143)

    monkeypatch.setattr(dataset, "evaluate", evaluating)
    before = signal.getsignal(signal.SIGTERM)
    argv = ["bench", "--dataset", str(corpus / "manifest.json"), "--json", str(tmp_path / "r")]
    with pytest.raises(SystemExit):
        cli.main(argv)
    (during,) = handlers
    assert during not in (signal.SIG_DFL, signal.SIG_IGN, before)
    assert signal.getsignal(signal.SIGTERM) == before


# -- through the real CLI, as a user runs it ---------------------------------------------------


def bench(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """``zenoh-perception bench --dataset ARGS`` as a subprocess."""
    return subprocess.run(
        cli_command("bench", "--dataset", *args),
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def one_line_error(run: subprocess.CompletedProcess[str]) -> str:
    """The single error line of a run that exited 2 (and printed no traceback)."""
    assert run.returncode == 2, (run.returncode, run.stdout, run.stderr)
    # the progress bar's lines (on stderr too) aside
    lines = [ln for ln in run.stderr.strip().splitlines() if not ln.startswith("[")]
    assert len(lines) == 1, run.stderr
    assert lines[0].startswith("zenoh-perception: error: "), lines[0]
    return lines[0]


def write_still(folder: Path, name: str, markers: list[tuple[int, float]], **kw: Any) -> None:
    """A 640x480 still of markers of the given ids and sides, side by side."""
    placed = [(tag, square(40 + 210 * k, 150, side)) for k, (tag, side) in enumerate(markers)]
    image = render_markers(W, H, placed, **kw)
    cv2.imwrite(str(folder / name), cv2.cvtColor(image, cv2.COLOR_BGRA2BGR))


def manifest_in(folder: Path, *items: dict[str, Any]) -> Path:
    path = folder / "manifest.json"
    path.write_text(json.dumps({"format": 1, "items": list(items)}), encoding="utf-8")
    return path


HOSTILE: Final = {
    "empty items": '{"format": 1, "items": []}',
    "empty item": '{"items": [{}]}',
    "glob name": json.dumps({"items": [labelled("**", "image", {"1": 1})]}),
    "1e400": '{"items": [{"name": "a", "kind": "image", "dictionary": "DICT_4X4_50",'
    ' "markers": {"1": 1e400}}]}',
    "NaN": '{"items": [{"name": "a", "kind": "image", "dictionary": "DICT_4X4_50",'
    ' "markers": {}, "unknown_markers": NaN}]}',
    "deep nesting": '{"items": [' + "[" * 100_000 + "]" * 100_000 + "]}",
    "huge count": json.dumps({"items": [labelled("a", "image", {"1": 10**18})]}),
    "huge id": json.dumps({"items": [labelled("a", "image", {"9" * 5000: 1})]}),
    "huge int": '{"items": [{"name": "a", "kind": "image", "dictionary": "DICT_4X4_50",'
    ' "markers": {}, "unknown_markers": ' + "9" * 5000 + "}]}",
    "markers a list": json.dumps(
        {"items": [{**labelled("a", "image", {}), "markers": [["1", 1]]}]}
    ),
    "no kind": '{"items": [{"name": "a", "dictionary": "DICT_4X4_50", "markers": {}}]}',
    "not JSON": "{items: ",
    "not UTF-8": '{"items": ["\xff"]}',
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_hostile_manifest_is_one_line_and_exit_2(case: str, tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    path = tmp_path / "m.json"
    path.write_bytes(HOSTILE[case].encode("latin-1"))
    line = one_line_error(bench(str(path)))
    assert "Traceback" not in line
    assert str(path) in line or "item " in line, line


def test_a_manifest_that_is_not_a_regular_file_is_refused_unread(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)  # reading it would block: nobody writes
    assert "is not a regular file" in one_line_error(bench(str(fifo), timeout=60))
    assert "is not a regular file" in one_line_error(bench("/dev/zero", timeout=60))
    assert "is not a regular file" in one_line_error(bench(str(tmp_path)))
    huge = tmp_path / "huge.json"
    with huge.open("wb") as file:  # sparse: no disk used
        file.truncate(MANIFEST_MAX_BYTES + 1)
    assert "is larger than" in one_line_error(bench(str(huge)))
    assert "cannot read manifest" in one_line_error(bench(str(tmp_path / "none.json")))


def test_a_missing_file_names_the_users_folder(tmp_path: Path) -> None:
    manifest = manifest_in(tmp_path, labelled("photo", "image", {"3": 1}))
    line = one_line_error(bench(str(manifest)))
    assert f"item photo: no file photo.<ext> in {tmp_path}" in line
    assert "--data" in line
    assert "rebuild" not in line
    line = one_line_error(bench(str(manifest), "--data", str(tmp_path / "nowhere")))
    assert "data folder" in line


def test_a_picture_over_max_frame_pixels_is_refused_and_listed(tmp_path: Path) -> None:
    write_still(tmp_path, "big.png", [(3, 120)])
    small = tmp_path / "small.toml"
    small.write_text("max_frame_pixels = 1000\n", encoding="utf-8")
    manifest = manifest_in(tmp_path, labelled("big", "image", {"3": 1}))
    line = one_line_error(bench(str(manifest), "--settings", str(small)))
    assert "every item was refused" in line
    assert "640x480 = 307200 pixels, more than max_frame_pixels = 1000" in line
    # beside a picture that fits, it is listed as refused and the rest is benched
    cv2.imwrite(str(tmp_path / "tiny.png"), np.full((20, 20, 3), 255, np.uint8))
    manifest = manifest_in(
        tmp_path, labelled("big", "image", {"3": 1}), labelled("tiny", "image", {})
    )
    out = tmp_path / "r.json"
    run = bench(str(manifest), "--settings", str(small), "--json", str(out))
    assert run.returncode == 0, run.stderr
    report = json.loads(out.read_text(encoding="utf-8"))
    assert [r["name"] for r in report["refused"]] == ["big"]
    assert [i["name"] for i in report["items"]] == ["tiny"]
    assert "  big: " in run.stdout


def test_a_huge_declared_png_is_refused_before_it_is_decoded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 16000 x 16000 declared by its header: decoding would take gigabytes
    _, small = cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))
    data = bytearray(small.tobytes())
    data[16:24] = (16000).to_bytes(4, "big") * 2
    (tmp_path / "bomb.png").write_bytes(bytes(data))
    decoded: list[object] = []
    monkeypatch.setattr(cv2, "imdecode", lambda *a: decoded.append(a))
    item = Item("bomb", "image", "DICT_4X4_50", {1: 1})
    with pytest.raises(DatasetError, match="16000x16000 = 256000000 pixels"):
        list(frames(item, tmp_path, max_frames=1))
    assert not decoded


def test_video_frames_are_streamed_not_held(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # every frame handed out is dropped once both detectors read it: at most the first
    # (kept for the size and the hint), the current one and the one before stay alive
    alive: list[weakref.ref[Any]] = []
    peak = 0

    def streamed(*_args: object) -> Iterator[Any]:
        nonlocal peak
        for k in range(12):
            gc.collect()
            peak = max(peak, sum(ref() is not None for ref in alive))
            image = render_markers(W, H, [(2, square(100 + 5 * k, 100, 90))])
            alive.append(weakref.ref(image))
            yield image

    monkeypatch.setattr(dataset, "frames", streamed)
    item = Item("clip", "video", "DICT_4X4_50", {2: 1})
    report = evaluate([item], tmp_path, Settings())
    assert report["items"][0]["service"]["found"] == 12
    assert peak <= 3, peak


def test_init_writes_a_manifest_to_fill_in_and_never_overwrites(tmp_path: Path) -> None:
    write_still(tmp_path, "desk.png", [(3, 120), (7, 100)])
    write_still(tmp_path, "empty.jpg", [])
    sequence = tmp_path / "walk"
    sequence.mkdir()
    for k in range(3):
        write_still(sequence, f"{k:03d}.png", [(5, 90)])
    (tmp_path / "notes.txt").write_text("not a picture", encoding="utf-8")
    run = bench("--init", str(tmp_path))
    assert run.returncode == 0, run.stderr
    manifest = tmp_path / "manifest.json"
    assert str(manifest) in run.stdout
    written = json.loads(manifest.read_text(encoding="utf-8"))
    assert [(i["name"], i["kind"]) for i in written["items"]] == [
        ("desk", "image"),
        ("empty", "image"),
        ("walk", "sequence"),
    ]
    assert all(i["markers"] == {"<id>": 1} for i in written["items"])
    # the dictionary too is a placeholder, not an answer: probe names it
    assert all(i["dictionary"] == DICTIONARY_PLACEHOLDER for i in written["items"])
    assert "zenoh-perception probe" in run.stdout
    # never overwritten
    before = manifest.read_bytes()
    assert "already exists" in one_line_error(bench("--init", str(tmp_path)))
    assert manifest.read_bytes() == before
    # left unfilled, the bench says which field of which item to fill in
    line = one_line_error(bench(str(manifest)))
    assert "item 0 (desk): field dictionary: is still the placeholder" in line
    for item in written["items"]:
        if item["name"] != "empty":  # a negative may keep it
            item["dictionary"] = "DICT_4X4_50"
    manifest.write_text(json.dumps(written), encoding="utf-8")
    line = one_line_error(bench(str(manifest)))
    assert "item 0 (desk): field markers: '<id>' is not a marker id" in line
    # filled in: the bench reads the folder itself (no data/ beside the manifest)
    fill = {"desk": {"3": 1, "7": 1}, "empty": {}, "walk": {"5": 1}}
    for item in written["items"]:
        item["markers"] = fill[item["name"]]
    manifest.write_text(json.dumps(written), encoding="utf-8")
    out, plot = tmp_path / "r.json", tmp_path / "plot.png"
    run = bench(str(manifest), "--json", str(out), "--plot", str(plot))
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads(out.read_text(encoding="utf-8"))
    assert report["all"]["service"]["found"] == 2 + 3
    assert "--dataset needs a MANIFEST" in one_line_error(
        subprocess.run(
            cli_command("bench", "--dataset"), capture_output=True, text=True, check=False
        )
    )


def test_a_wrong_dictionary_fails_saying_the_labels_are_probably_wrong(tmp_path: Path) -> None:
    # 4X4 markers labelled as 6X6 ones (what probe would have named, a user did not ask)
    write_still(tmp_path, "desk.png", [(3, 120), (7, 100)])
    write_still(tmp_path, "shelf.png", [(5, 110)])
    manifest = manifest_in(
        tmp_path,
        {"name": "desk", "kind": "image", "dictionary": "DICT_6X6_50", "markers": {"3": 1, "7": 1}},
        {"name": "shelf", "kind": "image", "dictionary": "DICT_6X6_50", "markers": {"5": 1}},
    )
    out = tmp_path / "r.json"
    run = bench(str(manifest), "--json", str(out))
    assert run.returncode == 1, run.stdout + run.stderr
    assert "the labels or the dictionary are probably wrong" in run.stderr
    goals = json.loads(out.read_text(encoding="utf-8"))["goals"]
    (labels,) = [g for g in goals if g["goal"].startswith("labelled markers found")]
    assert (labels["value"], labels["pass"]) == (0.0, False)
    # no row passes on nothing: no size bin without a marker is listed
    assert not [g for g in goals if " px: " in g["goal"] and g["value"] == 0 and g["pass"]]
    assert max(len(line) for line in run.stdout.splitlines()) <= 120


def test_the_plot_has_a_row_per_item_in_both_colours(tmp_path: Path) -> None:
    write_still(tmp_path, "one.png", [(3, 120)])
    write_still(tmp_path, "two.png", [(3, 120), (7, 100)])
    write_still(tmp_path, "five.png", [(4, 120)], dictionary="DICT_5X5_100")
    write_still(tmp_path, "blank.png", [])
    manifest = manifest_in(
        tmp_path,
        labelled("one", "image", {"3": 1}),
        labelled("two", "image", {"3": 1, "7": 1}),
        {**labelled("five", "image", {"4": 1}), "dictionary": "DICT_5X5_100"},
        labelled("blank", "image", {}),  # read in both dictionaries, drawn as one row
    )
    plot = tmp_path / "sub" / "plot.png"
    run = bench(str(manifest), "--plot", str(plot))
    assert run.returncode == 0, run.stderr
    image = cv2.imread(str(plot))
    assert image is not None
    for colour in (OPENCV_COLOUR, SERVICE_COLOUR):
        assert np.all(image == colour, axis=2).any(), colour
    # one row per item, then the size panel
    assert image.shape[0] == 80 + 26 * 4 + 60 + 26 * len(BUCKETS) * 2


def test_hints_say_which_family_or_flip_would_have_found_something(tmp_path: Path) -> None:
    # a 6X6 marker labelled as 4X4, and a 4X4 marker stored mirrored but not marked so
    write_still(tmp_path, "six.png", [(4, 160)], dictionary="DICT_6X6_250")
    shown = render_markers(W, H, [(3, square(200, 150, 160))])
    cv2.imwrite(str(tmp_path / "flip.png"), cv2.flip(cv2.cvtColor(shown, cv2.COLOR_BGRA2BGR), 1))
    manifest = manifest_in(
        tmp_path, labelled("six", "image", {"4": 1}), labelled("flip", "image", {"3": 1})
    )
    out = tmp_path / "r.json"
    run = bench(str(manifest), "--json", str(out))
    # OpenCV found nothing either: nothing lost; but no detector found the labelled markers,
    # so the labels or the dictionary are probably wrong: the run fails, saying so
    assert run.returncode == 1, run.stderr
    assert "the labels or the dictionary are probably wrong" in run.stderr
    hints = {i["name"]: i["hint"] for i in json.loads(out.read_text(encoding="utf-8"))["items"]}
    assert "DICT_6X6_1000 finds ids 4" in hints["six"]
    assert "DICT_4X4_1000 flipped left to right finds ids 3" in hints["flip"]
    assert "six (DICT_4X4_50): " + hints["six"] in run.stdout
    # an item where something is found has no hint
    write_still(tmp_path, "fine.png", [(3, 120)])
    assert nothing_found_hint(
        Item("x", "image", "DICT_4X4_50", {3: 1}), np.zeros((8, 8, 4), np.uint8)
    ).startswith("no family")


def test_exit_rules_false_ids_and_lost_tags(tmp_path: Path) -> None:
    # a sure still with a 30 px marker nobody labelled beside a labelled 150 px one
    write_still(tmp_path, "desk.png", [(3, 150), (9, 30)])
    sure = labelled("desk", "image", {"3": 1})
    out = tmp_path / "r.json"

    def run(item: dict[str, Any], *args: str) -> tuple[int, dict[str, Any], str]:
        result = bench(str(manifest_in(tmp_path, item)), "--json", str(out), *args)
        assert result.returncode in (0, 1), result.stderr
        return result.returncode, json.loads(out.read_text(encoding="utf-8")), result.stdout

    code, report, text = run(sure)
    assert code == 1  # the service reports the unlabelled id on a sure positive
    (failed,) = [g for g in report["goals"] if not g["pass"]]
    assert failed["goal"] == "sure positives: unlabelled ids (service)"
    assert "desk DICT_4X4_50 (1/1)" in failed["note"]
    # the same labels, unsure: the extra id is reported, not failed
    code, report, _ = run({**sure, "unsure": True})
    assert code == 0
    assert report["items"][0]["service"]["false_ids"] == 1
    # a service that drops the small marker reports no false id where OpenCV reports one: a win
    veto = tmp_path / "veto.toml"
    veto.write_text("min_tag_side_px = 60\n", encoding="utf-8")
    code, report, text = run(sure, "--settings", str(veto))
    assert code == 0, [g for g in report["goals"] if not g["pass"]]
    item = report["items"][0]
    assert (item["opencv"]["false_ids"], item["service"]["false_ids"]) == (1, 0)
    assert "1/0" in text
    # a service that drops every tag loses the one OpenCV finds, id by id
    blind = tmp_path / "blind.toml"
    blind.write_text("min_tag_side_px = 1000\n", encoding="utf-8")
    code, report, _ = run(sure, "--settings", str(blind))
    assert code == 1
    lost = next(g for g in report["goals"] if g["goal"].startswith("every tag OpenCV"))
    assert (lost["value"], lost["pass"]) == (1, False)
    assert "desk id 3" in lost["note"]
    assert report["items"][0]["service"]["missed"] == {"3": 1}
