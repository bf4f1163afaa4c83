"""``zenoh-perception bench --dataset MANIFEST``: the service's detector against OpenCV's default
detector on labelled pictures and videos (a camera's own, or the project's real corpus).

The manifest (``corpus/README.md`` describes it) names each item (a still, a video file or a
sequence of frames), its dictionary and the ids a person read on it. Every frame is turned
into the BGRA image a camera delivers and run through:

- ``opencv``: OpenCV's default detector as a user would run it (BGRA -> BGR, then
  ``cv2.aruco.ArucoDetector(dictionary, DetectorParameters()).detectMarkers``), timed with
  its conversion;
- ``service``: the service's detector with the given settings (default settings unless told),
  as the service runs it (grey conversion included), one instance per stream: the stills of
  one dictionary form one stream, each video another.

A reported id is *found* when the item's labels hold it (at most as many times as labelled),
else it is a *false id* (an item with no marker is a negative: every id on it is false, in
every dictionary the manifest uses). Markers a person saw but could not read
(``unknown_markers``) absorb as many unlabelled ids, reported as ``unverified``. Found markers
are also counted by their mean side in pixels (size buckets).

With ``--e2e`` each video also goes, frame by frame in lockstep, through service processes
(``zenoh-perception run``, default and ``--detector opencv``) and through the transport floor
(:mod:`zenoh_perception.bench.floor`), as one stream per video; a service's own cost is its end
to end time minus the floor's.

Goals (exit code 1 when one fails): on the stills in total, per dictionary and per size
bucket, and on every video, the service finds at least what OpenCV's default finds; it reports
no false id on the negatives and no more false ids than OpenCV elsewhere; with ``--e2e``, the
service's mean own cost on the videos is at most half OpenCV's mean detection time.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.bench import detectors as bench
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, dictionary_name
from zenoh_perception.errors import PerceptionError
from zenoh_perception.settings import Settings
from zenoh_perception.tags.geometry import mean_side

Image = npt.NDArray[np.uint8]

KINDS: Final = ("image", "video", "sequence")
#: Upper edges of the size buckets (mean side of a found marker, pixels).
SIZE_EDGES: Final = (24.0, 48.0, 96.0, 192.0)
#: Goal: the service's mean own cost on video / OpenCV's mean detection time.
VIDEO_OWN_COST_RATIO: Final = 0.5


class DatasetError(PerceptionError):
    """The manifest is malformed, or an item's file is missing or unreadable."""


def size_bucket(side_px: float) -> str:
    """The name of the size bucket of a marker whose mean side is ``side_px``."""
    low = 0.0
    for edge in SIZE_EDGES:
        if side_px < edge:
            return f"{low:.0f}-{edge:.0f} px"
        low = edge
    return f">= {low:.0f} px"


BUCKETS: Final = (*(size_bucket(edge - 1.0) for edge in SIZE_EDGES), size_bucket(SIZE_EDGES[-1]))


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
        item = Item(
            name=name,
            kind=kind,
            dictionary=dictionary_name(str(raw["dictionary"])),
            markers=markers,
            unknown_markers=int(raw.get("unknown_markers", 0)),
            unsure=bool(raw.get("unsure", False)),
            camera=str(raw.get("camera", "unknown")),
            conditions=tuple(str(c) for c in raw.get("conditions", ())),
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
    """The item's frames as BGRA images (a video: at most ``max_frames``).

    Raises:
        DatasetError: missing or unreadable file.

    """
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
class Score:
    """What one detector did on a group of frames."""

    frames: int = 0
    labelled: int = 0  # labelled markers over the frames (id-frames on video)
    found: int = 0
    false_ids: int = 0
    unverified: int = 0
    times_ms: list[float] = field(default_factory=list)
    buckets: Counter[str] = field(default_factory=Counter)
    false_examples: Counter[int] = field(default_factory=Counter)

    def add(self, item: Item, detections: Sequence[Detection], ms: float) -> None:
        self.frames += 1
        self.times_ms.append(ms)
        self.labelled += sum(item.markers.values())
        left = dict(item.markers)
        unknown = item.unknown_markers
        for detection in detections:
            if left.get(detection.tag_id, 0) > 0:
                left[detection.tag_id] -= 1
                self.found += 1
                self.buckets[size_bucket(mean_side(detection.corners))] += 1
            elif unknown > 0:
                unknown -= 1
                self.unverified += 1
            else:
                self.false_ids += 1
                self.false_examples[detection.tag_id] += 1

    def extend(self, other: Score) -> None:
        self.frames += other.frames
        self.labelled += other.labelled
        self.found += other.found
        self.false_ids += other.false_ids
        self.unverified += other.unverified
        self.times_ms += other.times_ms
        self.buckets.update(other.buckets)
        self.false_examples.update(other.false_examples)

    def summary(self) -> dict[str, Any]:
        times = np.asarray(self.times_ms, dtype=np.float64)
        return {
            "frames": self.frames,
            "labelled": self.labelled,
            "found": self.found,
            "false_ids": self.false_ids,
            "unverified": self.unverified,
            "median_ms": round(float(np.median(times)), 3) if times.size else None,
            "mean_ms": round(float(times.mean()), 3) if times.size else None,
            "buckets": {b: self.buckets.get(b, 0) for b in BUCKETS},
            "false_examples": {str(k): v for k, v in sorted(self.false_examples.items())},
        }


class _Runner(Protocol):
    """A detector as the bench runs it: detections and milliseconds for one BGRA image."""

    def run(self, image: Image) -> tuple[list[Detection], float]: ...


def _runners(dictionary: str, settings: Settings) -> dict[str, _Runner]:
    """OpenCV's default the way a user runs it, and the service's detector as it runs it."""
    detector = make_detector(
        settings.detector, dictionary, full_scan_period=settings.full_scan_period
    )
    return {
        "opencv": bench.Baseline(dictionary),
        "service": bench.Project(dictionary, detector, settings.min_tag_side_px),
    }


WHO: Final = ("opencv", "service")


@dataclass(slots=True)
class _Streams:
    """One runner pair per stream key (a dictionary's stills, or a video)."""

    settings: Settings
    runners: dict[str, dict[str, _Runner]] = field(default_factory=dict)

    def pair(self, key: str, dictionary: str) -> dict[str, _Runner]:
        if key not in self.runners:
            self.runners[key] = _runners(dictionary, self.settings)
        return self.runners[key]


def _run_frames(
    item: Item, images: Sequence[Image], runners: dict[str, _Runner], scores: dict[str, Score]
) -> None:
    for index, image in enumerate(images):
        order = WHO if index % 2 == 0 else WHO[::-1]
        for who in order:
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
    progress: bench.Progress | None = None,
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
            scores = {who: Score() for who in WHO}
            _run_frames(item, images, streams.pair(key, dictionary), scores)
            row: dict[str, Any] = {
                "name": item.name,
                "kind": item.kind,
                "dictionary": dictionary,
                "negative": item.negative,
                "unsure": item.unsure,
                "camera": item.camera,
                "size": [int(images[0].shape[1]), int(images[0].shape[0])],
                **{who: scores[who] for who in WHO},
            }
            if e2e and videos and not item.negative:
                row["e2e"] = _end_to_end(item, images, shm, progress)
            rows.append(row)
        if progress is not None:
            progress.step(item.name)
    return _report(rows, settings, max_video_frames)


def _end_to_end(
    item: Item, images: Sequence[Image], shm: bool, progress: bench.Progress | None
) -> dict[str, Any]:
    run = bench.lockstep_images(
        (*bench.E2E_DETECTORS, bench.FLOOR),
        images,
        progress,
        f"e2e {item.name}",
        dictionary=item.dictionary,
        shm=shm,
    )
    out: dict[str, Any] = {"camera": run.camera}
    bare = np.asarray(run.bare_ms, dtype=np.float64)
    out["opencv_detection"] = {
        "median_ms": round(float(np.median(bare)), 3),
        "mean_ms": round(float(bare.mean()), 3),
    }
    for name, latencies in run.latencies_ms.items():
        values = np.asarray(latencies, dtype=np.float64)
        score = Score()
        for seq in range(len(images)):
            record = run.records[name].get(seq)
            score.add(item, bench._detections(record), float(values[seq]))
        out[name] = {
            "median_ms": round(float(np.median(values)), 3),
            "mean_ms": round(float(values.mean()), 3),
            "found": score.found,
            "false_ids": score.false_ids,
            "records": len(run.records[name]),
        }
    return out


def _pool(rows: Sequence[dict[str, Any]]) -> dict[str, Score]:
    pooled = {who: Score() for who in WHO}
    for row in rows:
        for who in WHO:
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
        "items": [{**r, **{who: r[who].summary() for who in WHO}} for r in rows],
        "groups": {name: {who: s.summary() for who, s in g.items()} for name, g in groups.items()},
    }
    report["goals"] = goals(report)
    return report


def goals(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Every goal of the dataset bench with its value, threshold and PASS / FAIL."""
    rows: list[dict[str, Any]] = []

    def goal(name: str, value: float, limit: str, passed: bool, note: str = "") -> None:
        rows.append(
            {"goal": name, "value": value, "threshold": limit, "pass": passed, "note": note}
        )

    groups = report["groups"]
    for name, group in groups.items():
        if name == "negatives" or group["service"]["frames"] == 0:
            continue
        found, base = group["service"]["found"], group["opencv"]["found"]
        goal(f"{name}: found >= OpenCV default", found, f">= {base}", found >= base)
        if name == "stills":
            for bucket in BUCKETS:
                found = group["service"]["buckets"][bucket]
                base = group["opencv"]["buckets"][bucket]
                goal(
                    f"stills {bucket}: found >= OpenCV default", found, f">= {base}", found >= base
                )
        if name in ("stills", "videos"):
            fp, base_fp = group["service"]["false_ids"], group["opencv"]["false_ids"]
            goal(f"{name}: false ids <= OpenCV default", fp, f"<= {base_fp}", fp <= base_fp)
    if groups["negatives"]["service"]["frames"]:
        fp = groups["negatives"]["service"]["false_ids"]
        base_fp = groups["negatives"]["opencv"]["false_ids"]
        goal("negatives: false ids", fp, "== 0", fp == 0, f"OpenCV default: {base_fp}")
    chosen = report["settings"]["detector"]
    own: dict[str, float] = dict.fromkeys(bench.E2E_DETECTORS, 0.0)
    bare = 0.0
    for item in report["items"]:
        if item["kind"] == "image" or item["negative"]:
            continue
        found, base = item["service"]["found"], item["opencv"]["found"]
        goal(f"video {item['name']}: found >= OpenCV default", found, f">= {base}", found >= base)
        e2e = item.get("e2e")
        if e2e is None:
            continue
        frames_ = item["service"]["frames"]
        for name in bench.E2E_DETECTORS:
            own[name] += (e2e[name]["mean_ms"] - e2e[bench.FLOOR]["mean_ms"]) * frames_
        bare += e2e["opencv_detection"]["mean_ms"] * frames_
        found = e2e[chosen]["found"]
        goal(
            f"video {item['name']}: found by the service process >= OpenCV default",
            found,
            f">= {base}",
            found >= base,
        )
    if bare > 0.0:
        ratio = own[chosen] / bare
        others = ", ".join(
            f"detector={name}: {own[name] / bare:.3f}" for name in own if name != chosen
        )
        goal(
            f"videos: service (detector={chosen}) mean e2e - floor / OpenCV mean detection",
            round(ratio, 3),
            f"<= {VIDEO_OWN_COST_RATIO}",
            ratio <= VIDEO_OWN_COST_RATIO,
            f"frame-weighted over the videos; {others}",
        )
    return rows


def _ms(value: Any) -> str:
    return "-" if value is None else f"{value:.2f}"


def format_report(report: dict[str, Any]) -> str:
    """The human-readable tables."""
    parts: list[str] = []
    headers = ["group", "frames", "labelled"]
    for who in WHO:
        headers += [f"{who} found", f"{who} false", f"{who} med ms", f"{who} mean ms"]
    rows = []
    for name, group in report["groups"].items():
        row = [name, str(group["opencv"]["frames"]), str(group["opencv"]["labelled"])]
        for who in WHO:
            s = group[who]
            row += [str(s["found"]), str(s["false_ids"]), _ms(s["median_ms"]), _ms(s["mean_ms"])]
        rows.append(row)
    parts.append(
        "Totals (found = labelled markers reported; on video, id-frames)\n"
        + bench._table(headers, rows)
    )
    stills = report["groups"]["stills"]
    rows = [
        [
            bucket,
            str(stills["opencv"]["buckets"][bucket]),
            str(stills["service"]["buckets"][bucket]),
        ]
        for bucket in BUCKETS
    ]
    parts.append(
        "Stills by marker size (mean side)\n"
        + bench._table(["size", "opencv found", "service found"], rows)
    )
    rows = []
    for item in report["items"]:
        row = [
            item["name"] + (" (unsure)" if item["unsure"] else ""),
            item["kind"],
            item["dictionary"],
            f"{item['size'][0]}x{item['size'][1]}",
            str(item["opencv"]["frames"]),
            str(item["opencv"]["labelled"]),
        ]
        for who in WHO:
            s = item[who]
            row += [f"{s['found']}/{s['false_ids']}", _ms(s["mean_ms"])]
        rows.append(row)
    parts.append(
        "Items (found/false ids, mean ms per frame)\n"
        + bench._table(
            [
                "item",
                "kind",
                "dictionary",
                "size",
                "frames",
                "labelled",
                "opencv",
                "ms",
                "service",
                "ms",
            ],
            rows,
        )
    )
    e2e_rows = []
    for item in report["items"]:
        e2e = item.get("e2e")
        if e2e is None:
            continue
        bare = e2e["opencv_detection"]["mean_ms"]
        floor = e2e[bench.FLOOR]["mean_ms"]
        for name in (*bench.E2E_DETECTORS, bench.FLOOR):
            s = e2e[name]
            own = s["mean_ms"] - floor
            e2e_rows.append(
                [
                    item["name"],
                    name,
                    _ms(s["median_ms"]),
                    _ms(s["mean_ms"]),
                    "-" if name == bench.FLOOR else _ms(own),
                    "-" if name == bench.FLOOR else f"{own / bare:.2f}",
                    _ms(bare),
                    str(s["found"]),
                ]
            )
    if e2e_rows:
        parts.append(
            "Videos end to end (lockstep through service processes; own = mean e2e - floor)\n"
            + bench._table(
                [
                    "video",
                    "process",
                    "med ms",
                    "mean ms",
                    "own ms",
                    "own / opencv",
                    "opencv ms",
                    "found",
                ],
                e2e_rows,
            )
        )
    rows = [
        [g["goal"], str(g["value"]), g["threshold"], "PASS" if g["pass"] else "FAIL", g["note"]]
        for g in report["goals"]
    ]
    parts.append("Goals\n" + bench._table(["goal", "value", "threshold", "result", "note"], rows))
    return "\n\n".join(parts)


def main(args: argparse.Namespace, settings: Settings) -> int:
    """Run the dataset bench from parsed ``bench`` arguments; 1 when a goal fails."""
    manifest: Path = args.dataset
    data: Path = args.data if args.data is not None else manifest.parent / "data"
    items = load_manifest(manifest)
    progress = bench.Progress(len(items))
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
    print(format_report(report))
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
