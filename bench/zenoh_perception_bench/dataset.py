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
  as the service runs it (grey conversion included), one instance per stream: the stills of
  one dictionary form one stream, each video another.

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
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.detect.types import dictionary_name
from zenoh_perception.errors import PerceptionError, SettingsError
from zenoh_perception.files import read_text_file
from zenoh_perception.settings import Settings
from zenoh_perception.wire.image_header import image_header_size
from zenoh_perception_bench.e2e import LOCKSTEP_DEADLINE_MS, lockstep_images, record_detections
from zenoh_perception_bench.goals import LABELS_WRONG, dataset_goals
from zenoh_perception_bench.plot import plot_dataset
from zenoh_perception_bench.processes import E2E_DETECTORS, FLOOR, sigterm_exits
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.report import format_dataset_report
from zenoh_perception_bench.runners import PAIR, SHOWN, Baseline, Runner, pair, rotation
from zenoh_perception_bench.scoring import Labels, Score, rounded

Image = npt.NDArray[np.uint8]

KINDS: Final = ("image", "video", "sequence")
#: A manifest larger than this is refused before it is read (the corpus's is about 100 KB).
MANIFEST_MAX_BYTES: Final = 16 * 1024 * 1024
#: Most markers of one id, or unreadable ones, a manifest may state on one item.
MAX_COUNT: Final = 10_000
#: Fields an item must have; every other one has a default (docs/dataset.md).
REQUIRED: Final = ("name", "kind", "dictionary", "markers")
#: What ``--init`` lists: pictures (a still each), videos, and folders of pictures (sequences).
PICTURES: Final = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"})
VIDEOS: Final = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v"})
#: The placeholder ``--init`` writes for the ids to fill in; loading refuses it.
ID_PLACEHOLDER: Final = "<id>"
#: What ``--init`` writes for an item's dictionary: not a dictionary (``probe`` names it).
DICTIONARY_PLACEHOLDER: Final = "<dictionary: zenoh-perception probe FILE names it>"
#: The dictionary a negative keeping the placeholder is checked against (a negative is read
#: in every dictionary the manifest's positives use, whatever its own says).
_NEGATIVE_DICTIONARY: Final = "DICT_4X4_50"


class DatasetError(PerceptionError):
    """The manifest is malformed, or an item's file is missing, unreadable or too large."""


class TooLargeError(DatasetError):
    """An item's picture or frame has more pixels than ``max_frame_pixels``: the service
    would refuse it, and the bench does not decode it."""


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
    #: a video's or sequence's frames (0-based, first and last included) in which a labelled
    #: id is whole in the picture, by id; an id not listed is in every frame
    in_view: dict[int, tuple[tuple[int, int], ...]] = field(default_factory=dict)

    @property
    def negative(self) -> bool:
        return not self.markers and self.unknown_markers == 0

    @property
    def out_of_view(self) -> frozenset[int]:
        """None of the item's labelled ids is out of view (see :meth:`frame`)."""
        return frozenset()

    def frame(self, index: int) -> Labels:
        """The labels of the item's frame ``index``: its markers whole in that frame, and the
        others as out of view (reported there, a marker cut by the border is neither found
        nor false)."""
        if not self.in_view:
            return self
        gone = frozenset(
            tag
            for tag, spans in self.in_view.items()
            if not any(first <= index <= last for first, last in spans)
        )
        markers = {tag: count for tag, count in self.markers.items() if tag not in gone}
        return FrameLabels(markers, self.unknown_markers, gone)


@dataclass(frozen=True, slots=True)
class FrameLabels:
    """One frame's labels of a video whose markers come and go (:meth:`Item.frame`)."""

    markers: dict[int, int]
    unknown_markers: int
    out_of_view: frozenset[int]


def _shown(value: Any) -> str:
    """``value`` for a one-line message: repr, cut short."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _Fields:
    """Reads one item's fields; every mistake is one line naming the item and the field."""

    def __init__(self, raw: dict[str, Any], where: str) -> None:
        self.raw = raw
        self.where = where

    def fail(self, key: str, problem: str) -> DatasetError:
        return DatasetError(f"{self.where}: field {key}: {problem}")

    def text(self, key: str, default: str | None = None) -> str:
        if key not in self.raw:
            if default is None:
                raise self.fail(key, "required (docs/dataset.md lists the fields)")
            return default
        value = self.raw[key]
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"must be a non-empty string, not {_shown(value)}")
        return value

    def flag(self, key: str) -> bool:
        value = self.raw.get(key, False)
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false, not {_shown(value)}")
        return value

    def count(self, key: str, value: Any, low: int) -> int:
        # bool is an int to Python, 1e400 a float (inf) to json: both are refused here
        if not isinstance(value, int) or isinstance(value, bool):
            raise self.fail(key, f"must be a whole number, not {_shown(value)}")
        if not low <= value <= MAX_COUNT:
            raise self.fail(key, f"must be between {low} and {MAX_COUNT}, not {_shown(value)}")
        return value

    def markers(self, ids: int, dictionary: str) -> dict[int, int]:
        value = self.raw.get("markers", None)
        if "markers" not in self.raw:
            raise self.fail("markers", 'required: {"<id>": count, ...}, {} when there is none')
        if not isinstance(value, dict):
            raise self.fail("markers", f'must be a table {{"<id>": count}}, not {_shown(value)}')
        out: dict[int, int] = {}
        for key, count in value.items():
            if not (key.isdecimal() and key.isascii() and len(key) <= 6):
                raise self.fail(
                    "markers",
                    f'{_shown(key)} is not a marker id: write {{"3": 1}} for one marker of'
                    " id 3, {} when the picture holds none",
                )
            tag = int(key)
            if tag >= ids:
                raise self.fail("markers", f"id {tag} is not in {dictionary} (ids 0-{ids - 1})")
            out[tag] = self.count(f"markers {key}", count, 1)
        return out

    def in_view(self, markers: dict[int, int]) -> dict[int, tuple[tuple[int, int], ...]]:
        value = self.raw.get("in_view", {})
        shape = '{"<id>": [[first, last], ...]}: frames in which each labelled id is whole'
        if not isinstance(value, dict):
            raise self.fail("in_view", f"must be a table {shape}, not {_shown(value)}")
        out: dict[int, tuple[tuple[int, int], ...]] = {}
        for key, spans in value.items():
            if not (key.isdecimal() and key.isascii() and int(key) in markers):
                raise self.fail("in_view", f"{_shown(key)} is not one of the item's markers")
            if not isinstance(spans, list) or not all(
                isinstance(span, list) and len(span) == 2 for span in spans
            ):
                raise self.fail("in_view", f"id {key}: must be [[first, last], ...]")
            pairs = tuple(
                (self.count(f"in_view {key}", a, 0), self.count(f"in_view {key}", b, 0))
                for a, b in spans
            )
            if any(a > b for a, b in pairs):
                raise self.fail("in_view", f"id {key}: a span ends before it begins")
            out[int(key)] = pairs
        return out


def _dictionary_size(name: str) -> int:
    return int(aruco_dictionary(name).bytesList.shape[0])


def _item(raw: Any, index: int) -> Item:
    if not isinstance(raw, dict):
        msg = f"item {index}: must be a table {{...}}, not {_shown(raw)}"
        raise DatasetError(msg)
    fields = _Fields(raw, f"item {index}")
    name = fields.text("name")
    if (
        "/" in name
        or "\\" in name
        or name.startswith(".")
        or len(name) > 200
        or not name.isprintable()
    ):
        raise fields.fail(
            "name", f"must be a plain file name without its extension, not {_shown(name)}"
        )
    fields.where = f"item {index} ({name})"
    kind = fields.text("kind")
    if kind not in KINDS:
        raise fields.fail("kind", f"must be one of {', '.join(KINDS)}, not {_shown(kind)}")
    written = fields.text("dictionary")
    if written == DICTIONARY_PLACEHOLDER:
        if raw.get("markers") != {}:
            raise fields.fail(
                "dictionary",
                "is still the placeholder: `zenoh-perception probe FILE` names the markers' "
                "dictionary (a negative, markers {}, may keep it)",
            )
        written = _NEGATIVE_DICTIONARY
    try:
        dictionary = dictionary_name(written)
    except SettingsError as err:
        raise fields.fail("dictionary", str(err)) from err
    conditions = raw.get("conditions", [])
    if not isinstance(conditions, list) or not all(isinstance(c, str) for c in conditions):
        raise fields.fail("conditions", f"must be a list of words, not {_shown(conditions)}")
    markers = fields.markers(_dictionary_size(dictionary), dictionary)
    in_view = fields.in_view(markers)
    if in_view and kind == "image":
        raise fields.fail("in_view", "only a video or a sequence has frames to list")
    return Item(
        name=name,
        kind=kind,
        dictionary=dictionary,
        markers=markers,
        unknown_markers=fields.count("unknown_markers", raw.get("unknown_markers", 0), 0),
        unsure=fields.flag("unsure"),
        camera=fields.text("camera", "unknown"),
        conditions=tuple(conditions),
        mirrored=fields.flag("mirrored"),
        in_view=in_view,
    )


def _not_a_number(word: str) -> Any:
    msg = f"{word} is not a number a manifest may hold"
    raise ValueError(msg)


def _read_manifest(path: Path) -> Any:
    try:
        # a regular file only (/dev/zero or a FIFO would block or fill memory), size-bounded
        text = read_text_file(path, "manifest", MANIFEST_MAX_BYTES)
    except SettingsError as err:
        raise DatasetError(str(err)) from err
    try:
        return json.loads(text, parse_constant=_not_a_number)
    except RecursionError as err:
        msg = f"cannot read manifest {path}: JSON nested too deep"
        raise DatasetError(msg) from err
    except ValueError as err:
        one_line = " ".join(str(err).split())
        msg = f"cannot read manifest {path}: {one_line}"
        raise DatasetError(msg) from err


def load_manifest(path: Path) -> list[Item]:
    """The items of the manifest at ``path``.

    Raises:
        DatasetError: unreadable or malformed manifest (one line naming the item and field).

    """
    data = _read_manifest(path)
    if not isinstance(data, dict) or not isinstance(data.get("items"), list):
        msg = f'{path}: expected {{"format": 1, "items": [...]}} (docs/dataset.md)'
        raise DatasetError(msg)
    if data.get("format", 1) != 1:
        msg = f"{path}: field format: this bench reads format 1, not {_shown(data['format'])}"
        raise DatasetError(msg)
    if not data["items"]:
        msg = f"{path}: no items (bench --dataset --init FOLDER lists a folder's pictures)"
        raise DatasetError(msg)
    items = [_item(raw, i) for i, raw in enumerate(data["items"])]
    names = Counter(item.name for item in items)
    twice = sorted(name for name, count in names.items() if count > 1)
    if twice:
        msg = f"{path}: names used twice: {', '.join(twice)}"
        raise DatasetError(msg)
    return items


def data_folder(manifest: Path, data: Path | None) -> Path:
    """Where the items' files are: ``data`` if given, else ``data/`` beside the manifest if
    there is one, else the manifest's own folder (what ``--init`` writes for).

    Raises:
        DatasetError: that folder does not exist.

    """
    folder = data
    if folder is None:
        beside = manifest.parent / "data"
        folder = beside if beside.is_dir() else manifest.parent
    if not folder.is_dir():
        msg = f"data folder {folder} does not exist (pass --data FOLDER: your pictures' folder)"
        raise DatasetError(msg)
    return folder


def _file(data: Path, item: Item) -> Path:
    # exact names, not a glob: a name is the user's text, not a pattern
    try:
        found = sorted(p for p in data.iterdir() if p.stem == item.name and p.is_file())
    except OSError as err:
        msg = f"item {item.name}: cannot list {data}: {err.strerror}"
        raise DatasetError(msg) from err
    if not found:
        msg = (
            f"item {item.name}: no file {item.name}.<ext> in {data} (put the picture there,"
            " or pass --data with the folder that holds it)"
        )
        raise DatasetError(msg)
    return found[0]


def _bgra(image: Any) -> Image:
    if image.ndim == 2:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGRA), dtype=np.uint8)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2BGRA), dtype=np.uint8)


def _too_large(path: Path, width: int, height: int, max_pixels: int) -> TooLargeError:
    return TooLargeError(
        f"{path}: {width}x{height} = {width * height} pixels, more than max_frame_pixels ="
        f" {max_pixels} (raise it with --settings to bench this picture)"
    )


def _read_image(path: Path, max_pixels: int) -> Image:
    """A picture as BGRA, refused before it is decoded when its header declares more than
    ``max_pixels`` pixels (PNG and JPEG; other formats once decoded)."""
    try:
        size = path.stat().st_size
        # no picture of max_pixels needs more than 8 bytes a pixel (16-bit RGBA, stored)
        if size > 8 * max_pixels + (1 << 20):
            msg = f"{path}: {size} bytes, too large for max_frame_pixels = {max_pixels}"
            raise TooLargeError(msg)
        data = path.read_bytes()
    except OSError as err:
        msg = f"cannot read image {path}: {err.strerror}"
        raise DatasetError(msg) from err
    declared = image_header_size(data)
    if declared is not None and declared[0] * declared[1] > max_pixels:
        raise _too_large(path, *declared, max_pixels)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        msg = f"cannot read image {path}"
        raise DatasetError(msg)
    if image.shape[0] * image.shape[1] > max_pixels:
        raise _too_large(path, image.shape[1], image.shape[0], max_pixels)
    return _bgra(image)


DEFAULT_MAX_PIXELS: Final = Settings().limits.max_frame_pixels


def frames(
    item: Item, data: Path, max_frames: int, max_pixels: int = DEFAULT_MAX_PIXELS
) -> Iterator[Image]:
    """The item's frames as BGRA images, one at a time (a video: at most ``max_frames``),
    flipped back left to right when the item was stored mirrored.

    Raises:
        DatasetError: missing or unreadable file, or a frame of more than ``max_pixels``.

    """
    for image in _stored_frames(item, data, max_frames, max_pixels):
        yield np.asarray(cv2.flip(image, 1), np.uint8) if item.mirrored else image


def _stored_frames(item: Item, data: Path, max_frames: int, max_pixels: int) -> Iterator[Image]:
    if item.kind == "sequence":
        folder = data / item.name
        paths = sorted(p for p in folder.iterdir() if p.is_file()) if folder.is_dir() else []
        if not paths:
            msg = f"item {item.name}: no frames in {folder} (a sequence is a folder of pictures)"
            raise DatasetError(msg)
        for path in paths[:max_frames]:
            yield _read_image(path, max_pixels)
        return
    path = _file(data, item)
    if item.kind == "image":
        yield _read_image(path, max_pixels)
        return
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        msg = f"cannot open video {path}"
        raise DatasetError(msg)
    try:
        width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if width * height > max_pixels:
            raise _too_large(path, width, height, max_pixels)
        count = 0
        while count < max_frames:
            ok, image = capture.read()
            if not ok:
                break
            if image.shape[0] * image.shape[1] > max_pixels:
                raise _too_large(path, image.shape[1], image.shape[0], max_pixels)
            count += 1
            yield _bgra(image)
    finally:
        capture.release()
    if count == 0:
        msg = f"video {path} has no frame OpenCV can read"
        raise DatasetError(msg)


@dataclass(slots=True)
class _Streams:
    """One set of runners (:data:`SHOWN`) per stream key (a dictionary's stills, or a
    video)."""

    settings: Settings
    runners: dict[str, dict[str, Runner]] = field(default_factory=dict)

    def pair(self, key: str, dictionary: str) -> dict[str, Runner]:
        if key not in self.runners:
            self.runners[key] = pair(dictionary, self.settings.detection, best=True)
        return self.runners[key]


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
            key = f"video:{item.name}:{dictionary}" if videos else f"stills:{dictionary}"
            runners = streams.pair(key, dictionary)
            for who in rotation(SHOWN, index):
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


def _template(name: str, kind: str) -> dict[str, Any]:
    return {
        "name": name,
        "kind": kind,
        "dictionary": DICTIONARY_PLACEHOLDER,
        "markers": {ID_PLACEHOLDER: 1},
        "unknown_markers": 0,
        "unsure": False,
        "camera": "unknown",
        "mirrored": False,
        "conditions": [],
        "notes": "",
    }


def init_manifest(folder: Path) -> str:
    """Write ``folder/manifest.json`` listing the folder's pictures, videos and folders of
    pictures, with the fields to fill in; what was written, as a line for the user.

    Raises:
        DatasetError: no such folder, nothing to list, or a manifest is already there.

    """
    if not folder.is_dir():
        msg = f"--init {folder}: no such folder"
        raise DatasetError(msg)
    items: list[dict[str, Any]] = []
    skipped: list[str] = []
    names: set[str] = set()
    for path in sorted(folder.iterdir()):
        if path.name.startswith("."):
            continue
        suffix = path.suffix.lower()
        if path.is_dir():
            inside = [p for p in path.iterdir() if p.suffix.lower() in PICTURES and p.is_file()]
            kind = "sequence" if inside else ""
        elif path.is_file():
            kind = "image" if suffix in PICTURES else "video" if suffix in VIDEOS else ""
        else:
            kind = ""
        if not kind:
            continue
        name = path.name if kind == "sequence" else path.stem
        if name in names:  # photo.jpg beside photo.png: the bench reads one file per name
            skipped.append(path.name)
            continue
        names.add(name)
        items.append(_template(name, kind))
    if not items:
        msg = f"--init {folder}: no picture, video or folder of pictures in it"
        raise DatasetError(msg)
    manifest = folder / "manifest.json"
    text = json.dumps({"format": 1, "items": items}, indent=2) + "\n"
    try:
        with manifest.open("x", encoding="utf-8") as file:
            file.write(text)
    except FileExistsError as err:
        msg = f"{manifest} already exists: edit it, or move it away to write a new one"
        raise DatasetError(msg) from err
    except OSError as err:
        msg = f"cannot write {manifest}: {err.strerror}"
        raise DatasetError(msg) from err
    kinds = Counter(i["kind"] for i in items)
    listed = ", ".join(f"{n} {k}{'s' if n > 1 else ''}" for k, n in sorted(kinds.items()))
    note = f" (skipped, same name as another: {', '.join(skipped)})" if skipped else ""
    return (
        f"wrote {manifest}: {listed}{note}. Fill in each item's dictionary (zenoh-perception "
        f"probe {folder} names them) and markers"
        f' ({{"<id>": count}}, {{}} when none; docs/dataset.md), then run'
        f" zenoh-perception bench --dataset {manifest}"
    )


def _plain(value: Any) -> Any:
    if isinstance(value, Score):
        return value.summary()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    msg = f"not JSON: {type(value).__name__}"
    raise TypeError(msg)
