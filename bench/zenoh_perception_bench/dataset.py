"""``zenoh-perception bench --dataset MANIFEST``: the service's detector against OpenCV's default
detector, OpenCV's best setting shown beside, on labelled pictures and videos (a camera's own,
or the project's real corpus).

The manifest (``docs/dataset.md`` describes it; ``--init FOLDER`` writes one to fill in) names
each item (a still, a video file or a sequence of frames), its dictionary and the ids a person
read on it. Every frame, read one at a time, is turned into the BGRA image a camera delivers
and run through the three
:mod:`~zenoh_perception_bench.runners` of :data:`~zenoh_perception_bench.runners.SHOWN`:

- ``opencv``: OpenCV's default detector as a user would run it, timed with its conversion;
- ``best``: the same with OpenCV's best setting measured
  (:data:`~zenoh_perception_bench.runners.BEST_SETTING`), shown beside, not judged;
- ``service``: the service's detector with the given settings (default settings unless told),
  as the service runs it (grey conversion included), one instance per stream: each video
  (and dictionary) is a stream, and each still is read by runners of its own, so nothing one
  picture left in a detector (tracks, the second look's schedule, the veto's memory of the
  frame before) changes how the next is read, whatever the items' order.

Each is scored against the labels (:class:`~zenoh_perception_bench.scoring.Score`; an item
with no marker is a negative: every id on it is false, in every dictionary the manifest uses).
On an item where neither OpenCV's default nor the service found anything, OpenCV's default
tries the other families and the flipped picture (:func:`nothing_found_hint`).
With ``--e2e`` each video also goes, frame by frame in lockstep, through service processes
(``zenoh-perception run``, default and ``--detector opencv``) and through the transport floor
(:mod:`~zenoh_perception_bench.e2e`), as one stream per video. The verdicts are
:func:`~zenoh_perception_bench.goals.dataset_goals` (exit code 1 when one fails), the text
:func:`~zenoh_perception_bench.report.format_dataset_report`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np

from zenoh_perception.settings import Settings
from zenoh_perception_bench.e2e import LOCKSTEP_DEADLINE_MS, lockstep_images, record_detections
from zenoh_perception_bench.footage import Image, data_folder, frames
from zenoh_perception_bench.goals import LABELS_WRONG, dataset_goals
from zenoh_perception_bench.manifest import (
    DatasetError,
    Item,
    TooLargeError,
    init_manifest,
    load_manifest,
)
from zenoh_perception_bench.plot import plot_dataset
from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR, sigterm_exits
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.report import format_dataset_report
from zenoh_perception_bench.runners import PAIR, SHOWN, Baseline, Runner, pair, rotation
from zenoh_perception_bench.scoring import Score, rounded


@dataclass(slots=True)
class _Streams:
    """The runners (:data:`SHOWN`): one set per video and dictionary, kept over its frames
    (:meth:`video`); a fresh set for every still (:meth:`still`)."""

    settings: Settings
    runners: dict[str, dict[str, Runner]] = field(default_factory=dict)
    #: stills read so far: which detector goes first on the next one (:func:`rotation`)
    stills: int = 0

    def video(self, name: str, dictionary: str) -> dict[str, Runner]:
        key = f"{name}:{dictionary}"
        if key not in self.runners:
            self.runners[key] = pair(dictionary, self.settings.detection, best=True)
        return self.runners[key]

    def still(self, dictionary: str) -> tuple[dict[str, Runner], int]:
        """New runners for one still, and its place in the stills' order."""
        self.stills += 1
        return pair(dictionary, self.settings.detection, best=True), self.stills - 1


def evaluate(
    items: Sequence[Item],
    data: Path,
    settings: Settings,
    *,
    max_video_frames: int = 600,
    e2e: bool = False,
    shm: bool = True,
    progress: Progress | None = None,
    flags: Sequence[str] = (),
) -> dict[str, Any]:
    """Run the detectors over every item; the JSON-ready report (see the module doc).

    Frames are read one at a time and dropped once every detector saw them (with ``e2e``, a
    video's frames are kept for its lockstep replay).
    """
    streams = _Streams(settings)
    dictionaries = sorted({item.dictionary for item in items if not item.negative})
    dictionaries = dictionaries or ["DICT_4X4_50"]
    rows: list[dict[str, Any]] = []
    refused: list[dict[str, str]] = []
    for item in items:
        try:
            rows += _evaluate_item(
                item,
                data,
                streams,
                dictionaries=dictionaries,
                max_video_frames=max_video_frames,
                e2e=e2e,
                shm=shm,
                progress=progress,
                flags=flags,
            )
        except TooLargeError as err:
            refused.append({"name": item.name, "reason": str(err)})
        tick(progress, item.name)
    if not rows:
        msg = f"every item was refused: {refused[0]['reason']}" if refused else "no items"
        raise DatasetError(msg)
    return _report(rows, refused, settings, max_video_frames)


def _evaluate_item(
    item: Item,
    data: Path,
    streams: _Streams,
    *,
    dictionaries: Sequence[str],
    max_video_frames: int,
    e2e: bool,
    shm: bool,
    progress: Progress | None,
    flags: Sequence[str],
) -> list[dict[str, Any]]:
    """The item's rows: one per dictionary it is read in."""
    rows: list[dict[str, Any]] = []
    videos = item.kind != "image"
    tested = dictionaries if item.negative else [item.dictionary]
    scores = {d: {who: Score() for who in SHOWN} for d in tested}
    kept: list[Image] | None = [] if e2e and videos and not item.negative else None
    first: Image | None = None
    for index, image in enumerate(
        frames(item, data, max_video_frames, streams.settings.limits.max_frame_pixels)
    ):
        if first is None:
            first = image
        for dictionary in tested:
            if videos:
                runners, turn = streams.video(item.name, dictionary), index
            else:
                runners, turn = streams.still(dictionary)
            for who in rotation(SHOWN, turn):
                detections, ms = runners[who].run(image)
                scores[dictionary][who].add(item.frame(index), detections, ms)
        if kept is not None:
            kept.append(image)
    assert first is not None  # frames() raises on an item without any
    for dictionary in tested:
        row: dict[str, Any] = {
            "name": item.name,
            "kind": item.kind,
            "dictionary": dictionary,
            "negative": item.negative,
            "unsure": item.unsure,
            "camera": item.camera,
            "size": [int(first.shape[1]), int(first.shape[0])],
            **scores[dictionary],
            "hint": None,
        }
        if not item.negative and all(scores[dictionary][w].found == 0 for w in PAIR):
            unread = scores[dictionary]["service"].unverified == 0
            row["hint"] = nothing_found_hint(item, first) if unread else None
        if kept is not None:
            row["e2e"] = _end_to_end(item, kept, shm, progress, flags)
        rows.append(row)
    return rows


#: The largest dictionary of each family, tried on an item where nothing was found.
FAMILIES: Final = (
    "DICT_4X4_1000",
    "DICT_5X5_1000",
    "DICT_6X6_1000",
    "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL",
    "DICT_ARUCO_MIP_36h12",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11",
)


def nothing_found_hint(item: Item, image: Image) -> str:
    """What OpenCV's default finds on ``image`` (an item's first frame, on which nothing
    was found) in the other families and flipped left to right: a wrong dictionary or a
    mirrored picture shows up here."""
    found: list[str] = []
    for flipped in (False, True):
        picture = np.asarray(cv2.flip(image, 1), np.uint8) if flipped else image
        for dictionary in FAMILIES:
            if not flipped and dictionary == item.dictionary:
                continue
            detections, _ = Baseline(dictionary).run(picture)
            if detections:
                ids = sorted({d.tag_id for d in detections})
                shown = ", ".join(str(i) for i in ids[:6]) + (", ..." if len(ids) > 6 else "")
                how = " flipped left to right" if flipped else ""
                found.append(f"{dictionary}{how} finds ids {shown}")
    if not found:
        return "no family finds a marker on the first frame, flipped or not"
    return "; ".join(found[:3]) + ("; ..." if len(found) > 3 else "")


def _end_to_end(
    item: Item,
    images: Sequence[Image],
    shm: bool,
    progress: Progress | None,
    flags: Sequence[str],
) -> dict[str, Any]:
    run = lockstep_images(
        (*E2E_DETECTORS, FLOOR),
        images,
        progress,
        f"e2e {item.name}",
        dictionary=item.dictionary,
        shm=shm,
        # the lockstep waits for every frame's answer: a busy machine's default deadline would
        # abandon frames that are merely slow, as in the generated benches
        flags=("--frame-deadline-ms", str(LOCKSTEP_DEADLINE_MS), *flags),
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
            score.add(item.frame(seq), record_detections(record), float(values[seq]))
        out[name] = {
            "median_ms": rounded(np.median(values)),
            "mean_ms": rounded(values.mean()),
            "found": score.found,
            "false_ids": score.false_ids,
            "records": len(run.records[name]),
        }
    return out


def _pool(rows: Sequence[dict[str, Any]]) -> dict[str, Score]:
    pooled = {who: Score() for who in SHOWN}
    for row in rows:
        for who in SHOWN:
            pooled[who].extend(row[who])
    return pooled


def _report(
    rows: list[dict[str, Any]], refused: list[dict[str, str]], settings: Settings, max_frames: int
) -> dict[str, Any]:
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
    # every item read in a dictionary, negatives included: where the false ids come from
    by_dictionary = {
        d: _pool([r for r in rows if r["dictionary"] == d])
        for d in sorted({r["dictionary"] for r in rows})
    }
    everything = _pool(rows)

    def summaries(pooled: dict[str, dict[str, Score]]) -> dict[str, Any]:
        return {name: {who: s.summary() for who, s in g.items()} for name, g in pooled.items()}

    report: dict[str, Any] = {
        "settings": {
            "detector": settings.detection.detector,
            "full_scan_period": settings.detection.full_scan_period,
            "max_frame_pixels": settings.limits.max_frame_pixels,
        },
        "max_video_frames": max_frames,
        "items": [{**r, **{who: r[who].summary() for who in SHOWN}} for r in rows],
        "groups": summaries(groups),
        "dictionaries": summaries(by_dictionary),
        "all": {who: s.summary() for who, s in everything.items()},
        # items over max_frame_pixels, not decoded: the service would refuse their frames
        "refused": refused,
    }
    report["goals"] = dataset_goals(report)
    return report


def main(args: argparse.Namespace, settings: Settings) -> int:
    """Run the dataset bench from parsed ``bench`` arguments; 1 when a goal fails."""
    if args.init is not None:
        print(init_manifest(args.init))
        return 0
    if not args.dataset:  # ``bench --dataset`` with no manifest after it
        msg = "--dataset needs a MANIFEST (or --init FOLDER to write one)"
        raise DatasetError(msg)
    manifest = Path(args.dataset)
    items = load_manifest(manifest)
    data = data_folder(manifest, args.data)
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
                # the service processes of --e2e read the same settings file
                flags=("-s", str(args.settings)) if args.settings is not None else (),
            )
        finally:
            progress.close()
    print(format_dataset_report(report))
    if any(g["note"] == LABELS_WRONG for g in report["goals"]):
        print(f"zenoh-perception bench: {LABELS_WRONG}", file=sys.stderr)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, default=_plain) + "\n", encoding="utf-8")
    if args.plot is not None:
        plot_dataset(report, args.plot)
    return 0 if all(g["pass"] for g in report["goals"]) else 1


def _plain(value: Any) -> Any:
    if isinstance(value, Score):
        return value.summary()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    msg = f"not JSON: {type(value).__name__}"
    raise TypeError(msg)
