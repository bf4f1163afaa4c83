"""``bench --dataset``: labelled stills, sequences and videos, scored for OpenCV's default and
the service's detector side by side (made-up items: the real corpus is not in CI)."""

from __future__ import annotations

import json
import re
import signal
from pathlib import Path
from typing import Any

import cv2
import pytest

from tests.bench.conftest import H, W, labelled, square
from zenoh_perception.bench import dataset
from zenoh_perception.bench.dataset import DatasetError, Item, evaluate, frames, load_manifest
from zenoh_perception.bench.scoring import size_bucket
from zenoh_perception.cli import main as cli
from zenoh_perception.scene import render_markers
from zenoh_perception.settings import Settings


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
        "detector": settings.detector,
        "full_scan_period": settings.full_scan_period,
        "max_frame_pixels": settings.max_frame_pixels,
    }
    # the negative's false id fails that goal; every other goal passes
    failed = [g["goal"] for g in report["goals"] if not g["pass"]]
    assert failed == ["negatives: false ids (service)"]


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
        ({"items": [labelled("a", "image", [["1", 1]])]}, "item 0 (a): field markers: must be"),
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
