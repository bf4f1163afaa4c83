"""The manifest of ``bench --dataset``: labelled stills, videos and sequences
(``docs/dataset.md``), loaded and checked (:func:`load_manifest`), or written to fill in for a
folder of pictures (:func:`init_manifest`)."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from zenoh_perception.detect.opencv import aruco_dictionary
from zenoh_perception.detect.types import dictionary_name
from zenoh_perception.errors import PerceptionError, SettingsError
from zenoh_perception.files import read_text_file
from zenoh_perception_bench.scoring import Labels

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
