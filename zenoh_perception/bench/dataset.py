"""``zenoh-perception bench --dataset MANIFEST``: the service's detector against OpenCV's default
detector on labelled pictures and videos (a camera's own, or the project's real corpus).

The manifest (``corpus/README.md`` describes it) names each item (a still, a video file or a
sequence of frames), its dictionary and the ids a person read on it. Every frame is turned
into the BGRA image a camera delivers and run through the two
:mod:`~zenoh_perception.bench.runners` of :data:`~zenoh_perception.bench.runners.PAIR`:

- ``opencv``: OpenCV's default detector as a user would run it, timed with its conversion;
- ``service``: the service's detector with the given settings (default settings unless told),
  as the service runs it (grey conversion included), one instance per stream: the stills of
  one dictionary form one stream, each video another.

Each is scored against the labels (:class:`~zenoh_perception.bench.scoring.Score`; an item
with no marker is a negative: every id on it is false, in every dictionary the manifest uses).
With ``--e2e`` each video also goes, frame by frame in lockstep, through service processes
(``zenoh-perception run``, default and ``--detector opencv``) and through the transport floor
(:mod:`~zenoh_perception.bench.e2e`), as one stream per video. The verdicts are
:func:`~zenoh_perception.bench.goals.dataset_goals` (exit code 1 when one fails), the text
:func:`~zenoh_perception.bench.report.format_dataset_report`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.bench.e2e import lockstep_images, record_detections
from zenoh_perception.bench.goals import dataset_goals
from zenoh_perception.bench.processes import E2E_DETECTORS, FLOOR, sigterm_exits
from zenoh_perception.bench.progress import Progress, tick
from zenoh_perception.bench.report import format_dataset_report
from zenoh_perception.bench.runners import PAIR, Runner, pair, rotation
from zenoh_perception.bench.scoring import Score, rounded
from zenoh_perception.detect.types import dictionary_name
from zenoh_perception.errors import PerceptionError
from zenoh_perception.settings import Settings

Image = npt.NDArray[np.uint8]

KINDS: Final = ("image", "video", "sequence")


class DatasetError(PerceptionError):
    """The manifest is malformed, or an item's file is missing or unreadable."""


@dataclass(frozen=True, slots=True)
class Item:
    """One labelled still, video or sequence of the manifest."""

    name: str
    kind: str
    dictionary: str
    markers: dict[int, int]
    unknown_markers: int = 0
    unsure: bool = False
    camera: str = "unknown"
    conditions: tuple[str, ...] = ()
    mirrored: bool = False  # stored mirrored left to right by the capture software

    @property
    def negative(self) -> bool:
        return not self.markers and self.unknown_markers == 0


def _item(raw: Any, index: int) -> Item:
    if not isinstance(raw, dict):
        msg = f"item {index} is not a table"
        raise DatasetError(msg)
    try:
        name = str(raw["name"])
        kind = str(raw["kind"])
        markers = {int(k): int(v) for k, v in dict(raw.get("markers", {})).items()}
        mirrored = raw.get("mirrored", False)
        if not isinstance(mirrored, bool):
            msg = f"mirrored must be true or false, not {mirrored!r}"
            raise ValueError(msg)
        item = Item(
            name=name,
            kind=kind,
            dictionary=dictionary_name(str(raw["dictionary"])),
            markers=markers,
            unknown_markers=int(raw.get("unknown_markers", 0)),
            unsure=bool(raw.get("unsure", False)),
            camera=str(raw.get("camera", "unknown")),
            conditions=tuple(str(c) for c in raw.get("conditions", ())),
            mirrored=mirrored,
        )
    except (KeyError, TypeError, ValueError, PerceptionError) as err:
        msg = f"item {index} ({raw.get('name', '?')}): {err}"
        raise DatasetError(msg) from err
    if kind not in KINDS:
        msg = f"item {name}: kind must be one of {', '.join(KINDS)}, not {kind!r}"
        raise DatasetError(msg)
    if any(c < 1 for c in markers.values()) or item.unknown_markers < 0:
        msg = f"item {name}: marker counts must be positive"
        raise DatasetError(msg)
    if "/" in name or name.startswith("."):
        msg = f"item {name}: a name is a plain file name"
        raise DatasetError(msg)
    return item


def load_manifest(path: Path) -> list[Item]:
    """The items of the manifest at ``path``.

    Raises:
        DatasetError: unreadable or malformed manifest.

    """
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        msg = f"cannot read manifest {path}: {err}"
        raise DatasetError(msg) from err
    if not isinstance(data, dict) or not isinstance(data.get("items"), list):
        msg = f"{path}: expected {{'format': 1, 'items': [...]}}"
        raise DatasetError(msg)
    items = [_item(raw, i) for i, raw in enumerate(data["items"])]
    names = Counter(item.name for item in items)
    twice = sorted(name for name, count in names.items() if count > 1)
    if twice:
        msg = f"{path}: names used twice: {', '.join(twice)}"
        raise DatasetError(msg)
    return items


def _file(data: Path, item: Item) -> Path:
    found = sorted(p for p in data.glob(f"{item.name}.*") if p.is_file())
    if not found:
        msg = f"item {item.name}: no file {data / item.name}.* (rebuild the data folder)"
        raise DatasetError(msg)
    return found[0]


def _bgra(image: Any) -> Image:
    if image.ndim == 2:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGRA), dtype=np.uint8)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2BGRA), dtype=np.uint8)


def _read_image(path: Path) -> Image:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        msg = f"cannot read image {path}"
        raise DatasetError(msg)
    return _bgra(image)


def frames(item: Item, data: Path, max_frames: int) -> Iterator[Image]:
    """The item's frames as BGRA images (a video: at most ``max_frames``), flipped back left
    to right when the item was stored mirrored.

    Raises:
        DatasetError: missing or unreadable file.

    """
    for image in _stored_frames(item, data, max_frames):
        yield np.asarray(cv2.flip(image, 1), np.uint8) if item.mirrored else image


def _stored_frames(item: Item, data: Path, max_frames: int) -> Iterator[Image]:
    if item.kind == "sequence":
        folder = data / item.name
        paths = sorted(p for p in folder.iterdir() if p.is_file()) if folder.is_dir() else []
        if not paths:
            msg = f"item {item.name}: no frames in {folder}"
            raise DatasetError(msg)
        for path in paths[:max_frames]:
            yield _read_image(path)
        return
    path = _file(data, item)
    if item.kind == "image":
        yield _read_image(path)
        return
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        msg = f"cannot open video {path}"
        raise DatasetError(msg)
    try:
        count = 0
        while count < max_frames:
            ok, image = capture.read()
            if not ok:
                break
            count += 1
            yield _bgra(image)
    finally:
        capture.release()
    if count == 0:
        msg = f"video {path} has no frame OpenCV can read"
        raise DatasetError(msg)


@dataclass(slots=True)
class _Streams:
    """One runner pair per stream key (a dictionary's stills, or a video)."""

    settings: Settings
    runners: dict[str, dict[str, Runner]] = field(default_factory=dict)

    def pair(self, key: str, dictionary: str) -> dict[str, Runner]:
        if key not in self.runners:
            self.runners[key] = pair(dictionary, self.settings)
        return self.runners[key]


def _run_frames(
    item: Item, images: Sequence[Image], runners: dict[str, Runner], scores: dict[str, Score]
) -> None:
    for index, image in enumerate(images):
        for who in rotation(PAIR, index):
            detections, ms = runners[who].run(image)
            scores[who].add(item, detections, ms)


def evaluate(
    items: Sequence[Item],
    data: Path,
    settings: Settings,
    *,
    max_video_frames: int = 600,
    e2e: bool = False,
    shm: bool = True,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Run both detectors over every item; the JSON-ready report (see the module doc)."""
    streams = _Streams(settings)
    dictionaries = sorted({item.dictionary for item in items if not item.negative})
    dictionaries = dictionaries or ["DICT_4X4_50"]
    rows: list[dict[str, Any]] = []
    for item in items:
        videos = item.kind != "image"
        images = list(frames(item, data, max_video_frames))
        tested = dictionaries if item.negative else [item.dictionary]
        for dictionary in tested:
            key = f"video:{item.name}:{dictionary}" if videos else f"stills:{dictionary}"
            scores = {who: Score() for who in PAIR}
            _run_frames(item, images, streams.pair(key, dictionary), scores)
            row: dict[str, Any] = {
                "name": item.name,
                "kind": item.kind,
                "dictionary": dictionary,
                "negative": item.negative,
                "unsure": item.unsure,
                "camera": item.camera,
                "size": [int(images[0].shape[1]), int(images[0].shape[0])],
                **{who: scores[who] for who in PAIR},
            }
            if e2e and videos and not item.negative:
                row["e2e"] = _end_to_end(item, images, shm, progress)
            rows.append(row)
        tick(progress, item.name)
    return _report(rows, settings, max_video_frames)


def _end_to_end(
    item: Item, images: Sequence[Image], shm: bool, progress: Progress | None
) -> dict[str, Any]:
    run = lockstep_images(
        (*E2E_DETECTORS, FLOOR),
        images,
        progress,
        f"e2e {item.name}",
        dictionary=item.dictionary,
        shm=shm,
    )
    out: dict[str, Any] = {"camera": run.camera}
    bare = np.asarray(run.bare_ms, dtype=np.float64)
    out["opencv_detection"] = {
        "median_ms": rounded(np.median(bare)),
        "mean_ms": rounded(bare.mean()),
    }
    for name, latencies in run.latencies_ms.items():
        values = np.asarray(latencies, dtype=np.float64)
        score = Score()
        for seq in range(len(images)):
            record = run.records[name].get(seq)
            score.add(item, record_detections(record), float(values[seq]))
        out[name] = {
            "median_ms": rounded(np.median(values)),
            "mean_ms": rounded(values.mean()),
            "found": score.found,
            "false_ids": score.false_ids,
            "records": len(run.records[name]),
        }
    return out


def _pool(rows: Sequence[dict[str, Any]]) -> dict[str, Score]:
    pooled = {who: Score() for who in PAIR}
    for row in rows:
        for who in PAIR:
            pooled[who].extend(row[who])
    return pooled


def _report(rows: list[dict[str, Any]], settings: Settings, max_frames: int) -> dict[str, Any]:
    stills = [r for r in rows if r["kind"] == "image" and not r["negative"]]
    videos = [r for r in rows if r["kind"] != "image" and not r["negative"]]
    negatives = [r for r in rows if r["negative"]]
    groups: dict[str, dict[str, Score]] = {
        "stills": _pool(stills),
        "videos": _pool(videos),
        "negatives": _pool(negatives),
    }
    for dictionary in sorted({r["dictionary"] for r in stills}):
        groups[f"stills {dictionary}"] = _pool([r for r in stills if r["dictionary"] == dictionary])
    report: dict[str, Any] = {
        "settings": {"detector": settings.detector, "full_scan_period": settings.full_scan_period},
        "max_video_frames": max_frames,
        "items": [{**r, **{who: r[who].summary() for who in PAIR}} for r in rows],
        "groups": {name: {who: s.summary() for who, s in g.items()} for name, g in groups.items()},
    }
    report["goals"] = dataset_goals(report)
    return report


def main(args: argparse.Namespace, settings: Settings) -> int:
    """Run the dataset bench from parsed ``bench`` arguments; 1 when a goal fails."""
    manifest: Path = args.dataset
    data: Path = args.data if args.data is not None else manifest.parent / "data"
    items = load_manifest(manifest)
    progress = Progress(len(items))
    # SIGTERM stops the bench through the finally blocks that stop its service processes
    with sigterm_exits():
        try:
            report = evaluate(
                items,
                data,
                settings,
                max_video_frames=args.max_video_frames,
                e2e=args.e2e,
                shm=not args.no_shm,
                progress=progress,
            )
        finally:
            progress.close()
    print(format_dataset_report(report))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, default=_plain) + "\n", encoding="utf-8")
    return 0 if all(g["pass"] for g in report["goals"]) else 1


def _plain(value: Any) -> Any:
    if isinstance(value, Score):
        return value.summary()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    msg = f"not JSON: {type(value).__name__}"
    raise TypeError(msg)
