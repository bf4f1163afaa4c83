"""``bench --dataset``: labelled stills, sequences and videos, scored for OpenCV's default and
the service's detector side by side (made-up items here: the real corpus is not in CI)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.bench.dataset import (
    BUCKETS,
    DatasetError,
    Item,
    Score,
    evaluate,
    format_report,
    load_manifest,
    size_bucket,
)
from zenoh_perception.cli import main as cli
from zenoh_perception.detect.types import Detection
from zenoh_perception.scene import render_markers
from zenoh_perception.settings import Settings

W, H = 640, 480


def square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def bgr(image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2BGR), dtype=np.uint8)


def item(name: str, kind: str, markers: dict[str, int], **extra: Any) -> dict[str, Any]:
    return {"name": name, "kind": kind, "dictionary": "DICT_4X4_50", "markers": markers, **extra}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("corpus")
    data = root / "data"
    data.mkdir()
    two = render_markers(W, H, [(3, square(60, 60, 100)), (7, square(400, 200, 30))])
    cv2.imwrite(str(data / "two.png"), bgr(two))
    # id 9 is labelled, id 12 is a marker the labeller could not read
    one_known = render_markers(W, H, [(9, square(100, 100, 60)), (12, square(300, 300, 60))])
    cv2.imwrite(str(data / "unknown.png"), bgr(one_known))
    five = render_markers(W, H, [(4, square(200, 150, 120))], dictionary="DICT_5X5_100")
    cv2.imwrite(str(data / "five.jpg"), bgr(five))
    # a negative that holds a DICT_4X4_50 marker nobody labelled: a false id by definition
    cv2.imwrite(str(data / "n-empty.png"), bgr(render_markers(W, H, [(1, square(50, 50, 80))])))
    sequence = data / "walk"
    sequence.mkdir()
    for k in range(6):
        frame = render_markers(W, H, [(5, square(80 + 10 * k, 120, 90))])
        cv2.imwrite(str(sequence / f"{k:06d}.png"), bgr(frame))
    writer = cv2.VideoWriter(str(data / "clip.avi"), cv2.VideoWriter.fourcc(*"MJPG"), 10, (W, H))
    assert writer.isOpened()
    for k in range(8):
        writer.write(bgr(render_markers(W, H, [(2, square(300 - 8 * k, 200, 100))])))
    writer.release()
    manifest = {
        "format": 1,
        "items": [
            item("two", "image", {"3": 1, "7": 1}, camera="webcam"),
            item("unknown", "image", {"9": 1}, unknown_markers=1),
            {**item("five", "image", {"4": 1}), "dictionary": "DICT_5X5_100"},
            item("n-empty", "image", {}),
            item("walk", "sequence", {"5": 1}),
            item("clip", "video", {"2": 1}),
        ],
    }
    (root / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return root


def test_every_item_is_scored_for_both_detectors(corpus: Path) -> None:
    items = load_manifest(corpus / "manifest.json")
    report = evaluate(items, corpus / "data", Settings())
    rows = {(r["name"], r["dictionary"]): r for r in report["items"]}
    two = rows["two", "DICT_4X4_50"]
    assert two["opencv"]["found"] == two["service"]["found"] == 2
    assert two["service"]["labelled"] == 2
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
    assert groups["stills"]["service"]["found"] == 4
    assert groups["stills DICT_5X5_100"]["service"]["found"] == 1
    assert groups["videos"]["service"]["found"] == 14
    assert groups["stills"]["service"]["buckets"][size_bucket(100.0)] == 2  # 100, 120 px
    # the negative's false id fails that goal; every other goal passes
    failed = [g["goal"] for g in report["goals"] if not g["pass"]]
    assert failed == ["negatives: false ids"]
    text = format_report(report)
    assert "walk" in text
    assert "clip" in text


def test_a_video_is_read_up_to_max_frames(corpus: Path) -> None:
    items = [i for i in load_manifest(corpus / "manifest.json") if i.name == "clip"]
    report = evaluate(items, corpus / "data", Settings(), max_video_frames=3)
    assert report["items"][0]["service"]["frames"] == 3


def test_score_counts_labels_unknown_and_false_ids(tmp_path: Path) -> None:
    manifest = {"items": [item("x", "image", {"1": 2}, unknown_markers=1)]}
    (labelled,) = load_manifest_from(manifest, tmp_path)
    quad = square(0, 0, 30).astype(np.float32)
    score = Score()
    detections = [Detection(i, quad) for i in (1, 1, 1, 4, 5)]
    score.add(labelled, detections, 2.0)
    assert (score.found, score.unverified, score.false_ids) == (2, 1, 2)
    assert sum(score.buckets.values()) == 2
    assert score.summary()["buckets"][size_bucket(30.0)] == 2
    assert list(score.summary()["buckets"]) == list(BUCKETS)


def load_manifest_from(data: dict[str, Any], folder: Path) -> list[Item]:
    path = folder / "m.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return load_manifest(path)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"items": [item("a", "photo", {})]}, "kind must be"),
        ({"items": [{**item("a", "image", {}), "dictionary": "DICT_9X9"}]}, "dictionary"),
        ({"items": [item("a", "image", {"x": 1})]}, "item 0"),
        ({"items": [item("a", "image", {"1": 0})]}, "positive"),
        ({"items": [item("a", "image", {}), item("a", "image", {})]}, "used twice"),
        ({"items": [item("../a", "image", {})]}, "plain file name"),
        ({"things": []}, "expected"),
    ],
)
def test_malformed_manifests_are_refused(
    data: dict[str, Any], message: str, tmp_path: Path
) -> None:
    with pytest.raises(DatasetError, match=message):
        load_manifest_from(data, tmp_path)


def test_cli_exit_codes_follow_the_goals(corpus: Path, tmp_path: Path) -> None:
    manifest = corpus / "manifest.json"
    positives = json.loads(manifest.read_text(encoding="utf-8"))
    positives["items"] = [i for i in positives["items"] if i["name"] != "n-empty"]
    clean = corpus / "positives.json"
    clean.write_text(json.dumps(positives), encoding="utf-8")
    out = tmp_path / "report.json"
    assert cli.main(["bench", "--dataset", str(clean), "--json", str(out)]) == 0
    assert all(g["pass"] for g in json.loads(out.read_text(encoding="utf-8"))["goals"])
    # settings that drop every tag: the service finds less than OpenCV, the bench says so
    blind = tmp_path / "blind.toml"
    blind.write_text("min_tag_side_px = 1000\n", encoding="utf-8")
    argv = ["bench", "--dataset", str(clean), "--settings", str(blind)]
    assert cli.main(argv) == 1
    # a missing file is an error naming the item, exit 2
    assert cli.main(["bench", "--dataset", str(clean), "--data", str(tmp_path)]) == 2


def test_videos_go_end_to_end_through_service_processes_and_the_floor(corpus: Path) -> None:
    items = [i for i in load_manifest(corpus / "manifest.json") if i.name == "walk"]
    report = evaluate(items, corpus / "data", Settings(), e2e=True, shm=False)
    (row,) = report["items"]
    e2e = row["e2e"]
    assert set(e2e) >= {"opencv", "tracking", "floor", "opencv_detection", "camera"}
    for name in ("opencv", "tracking", "floor"):
        assert e2e[name]["records"] == 6  # every frame answered, in lockstep
    assert e2e["opencv"]["found"] == e2e["tracking"]["found"] == row["opencv"]["found"] == 6
    assert e2e["floor"]["found"] == 0  # the floor detects nothing: it only answers
    names = [g["goal"] for g in report["goals"]]
    assert "video walk: found by the service process >= OpenCV default" in names
    assert any(n.startswith("videos: service (detector=opencv) mean e2e - floor") for n in names)
