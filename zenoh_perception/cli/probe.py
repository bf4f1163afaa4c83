"""``zenoh-perception probe PATH...``: which dictionary are these markers?

Every frame read (photos, videos, image folders, rosbag2 Image topics: what ``replay`` reads)
goes once through OpenCV's detector with the largest dictionary of every family
(``detectMarkersMultiDict``: one candidate search, every family's bits), as it is and mirrored
left to right. Per file it prints which families and ids were found, in how many frames and how
large, and the ``run`` flags to use: the smallest dictionary of the family that holds every id
seen.

Each marker then goes through the service's veto (``verify``). A look-alike that passes it
can still decode as a valid id of some family on a frame or two: a family is proposed only
when it has at least a fifth of the tags (counted once per frame) of the family seen most,
and a family seen in a single frame of a video is marked as doubtful.
"""

from __future__ import annotations

import json
import math
import sys
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, TextIO

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.camera.sources import FrameSource, SourceFrame, open_source
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.errors import FrameDecodeError
from zenoh_perception.settings import Settings
from zenoh_perception.tags.geometry import mean_side
from zenoh_perception.wire.frames import decode_image_cdr, decode_raw_frame, to_gray

#: Each family's dictionaries, smallest first: a smaller one is the first ids of the largest
#: (OpenCV's predefined ArUco dictionaries are nested so), so the largest reads them all.
FAMILIES: Final[tuple[tuple[str, tuple[tuple[str, int], ...]], ...]] = (
    *(
        (bits, tuple((f"DICT_{bits}_{n}", n) for n in (50, 100, 250, 1000)))
        for bits in ("4X4", "5X5", "6X6", "7X7")
    ),
    ("ARUCO_ORIGINAL", (("DICT_ARUCO_ORIGINAL", 1024),)),
    ("APRILTAG_16h5", (("DICT_APRILTAG_16h5", 30),)),
    ("APRILTAG_25h9", (("DICT_APRILTAG_25h9", 35),)),
    ("APRILTAG_36h10", (("DICT_APRILTAG_36h10", 2320),)),
    ("APRILTAG_36h11", (("DICT_APRILTAG_36h11", 587),)),
    ("ARUCO_MIP_36h12", (("DICT_ARUCO_MIP_36h12", 250),)),
)
#: The dictionary each family is read with: its largest.
READ_WITH: Final = tuple(sizes[-1][0] for _family, sizes in FAMILIES)
#: A family is proposed when it has at least this share of the tags of the family seen most.
PROPOSE_SHARE: Final = 0.2
#: Frames read per file at most (spread evenly over a longer video or folder).
DEFAULT_MAX_FRAMES: Final = 300


@dataclass(slots=True)
class FamilyTally:
    """What one family's dictionary found over a file's frames."""

    frames: int = 0  # frames with at least one of its tags
    tags: int = 0  # its tags, counted once per frame they are in
    ids: dict[int, int] = field(default_factory=dict)  # id -> frames it was seen in
    sides: list[float] = field(default_factory=list)  # mean side of each tag, pixels

    def add(self, ids_sides: Sequence[tuple[int, float]]) -> None:
        self.frames += 1
        self.tags += len(ids_sides)
        for tag_id in {tag_id for tag_id, _side in ids_sides}:
            self.ids[tag_id] = self.ids.get(tag_id, 0) + 1
        self.sides += [side for _tag_id, side in ids_sides]


@dataclass(slots=True)
class Probe:
    """One file's answer."""

    path: str
    kind: str
    frames_read: int = 0
    frames_total: int | None = None
    found: dict[str, FamilyTally] = field(default_factory=lambda: defaultdict(FamilyTally))
    mirrored: dict[str, FamilyTally] = field(default_factory=lambda: defaultdict(FamilyTally))
    unreadable: int = 0  # frames that did not decode

    def proposal(self) -> list[str]:
        """The dictionaries to run with, most seen first (empty: nothing to propose)."""
        return _propose(self.found)

    def mirrored_only(self) -> list[str]:
        """Dictionaries found only on the mirrored picture: a mirroring camera."""
        return [] if self.proposal() else _propose(self.mirrored)

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "kind": self.kind,
            "frames_read": self.frames_read,
            "frames_total": self.frames_total,
            "unreadable": self.unreadable,
            "found": [_tally_dict(name, t) for name, t in _by_frames(self.found)],
            "mirrored": [_tally_dict(name, t) for name, t in _by_frames(self.mirrored)],
            "dictionary": ", ".join(self.proposal()) or None,
            "mirrored_only": ", ".join(self.mirrored_only()) or None,
        }


def smallest_dictionary(family_dictionary: str, ids: Iterable[int]) -> str:
    """The smallest dictionary of ``family_dictionary``'s family that holds every id."""
    top = max(ids, default=0)
    for _family, sizes in FAMILIES:
        if sizes[-1][0] == family_dictionary:
            return next(name for name, size in sizes if top < size)
    return family_dictionary


def _by_frames(found: dict[str, FamilyTally]) -> list[tuple[str, FamilyTally]]:
    return sorted(found.items(), key=lambda item: (-item[1].tags, -item[1].frames, item[0]))


def _propose(found: dict[str, FamilyTally]) -> list[str]:
    ranked = _by_frames(found)
    if not ranked:
        return []
    most = ranked[0][1].tags
    return [
        smallest_dictionary(name, tally.ids)
        for name, tally in ranked
        if tally.tags >= PROPOSE_SHARE * most
    ]


def _tally_dict(name: str, tally: FamilyTally) -> dict[str, Any]:
    return {
        "dictionary": smallest_dictionary(name, tally.ids),
        "frames": tally.frames,
        "tags": tally.tags,
        "ids": {str(k): v for k, v in sorted(tally.ids.items())},
        "side_px": [round(min(tally.sides), 1), round(max(tally.sides), 1)],
    }


def _sampled(source: FrameSource, max_frames: int) -> Iterator[SourceFrame]:
    total = source.count
    step = 1 if not total or total <= max_frames else math.ceil(total / max_frames)
    taken = 0
    frames = source.frames()
    try:
        for index, frame in enumerate(frames):
            if index % step == 0:
                yield frame
                taken += 1
                if taken >= max_frames:
                    return
    finally:
        frames.close()


def _grey(frame: SourceFrame, max_pixels: int) -> npt.NDArray[np.uint8]:
    if frame.attachment is not None:
        decoded = decode_raw_frame(frame.payload, frame.attachment, max_pixels=max_pixels)
    else:
        decoded = decode_image_cdr(frame.payload, max_pixels=max_pixels)
    return to_gray(decoded)


def probe(path: Path, *, max_frames: int = DEFAULT_MAX_FRAMES, topic: str | None = None) -> Probe:
    """Read up to ``max_frames`` frames of ``path`` and tally what every family finds.

    Raises:
        ReplayError: the path cannot be read as a replay source.

    """
    source = open_source(path, topic=topic)
    result = Probe(str(path), source.kind, frames_total=source.count)
    detector = OpenCvDetector(", ".join(READ_WITH))
    # the service's veto, so that look-alikes (key-caps, lettering) propose no family
    verifier = Verifier(", ".join(READ_WITH))
    max_pixels = Settings().limits.max_frame_pixels
    for frame in _sampled(source, max_frames):
        try:
            grey = _grey(frame, max_pixels)
        except FrameDecodeError:
            result.unreadable += 1
            continue
        result.frames_read += 1
        mirrored = np.ascontiguousarray(cv2.flip(grey, 1), dtype=np.uint8)
        for tallies, image in ((result.found, grey), (result.mirrored, mirrored)):
            per_family: dict[str, list[tuple[int, float]]] = defaultdict(list)
            kept, _vetoed = verifier.verify(image, detector.detect(image))
            for detection in kept:
                per_family[detection.dictionary].append(
                    (detection.tag_id, mean_side(detection.corners))
                )
            for name, ids_sides in per_family.items():
                tallies[name].add(ids_sides)
    return result


def format_probe(result: Probe) -> str:
    """The human-readable answer for one file."""
    total = "" if result.frames_total is None else f" of {result.frames_total}"
    lines = [f"{result.path}: {result.kind}, {result.frames_read}{total} frames read"]
    if result.unreadable:
        lines.append(f"  {result.unreadable} frames could not be decoded")
    for name, tally in _by_frames(result.found):
        lines.append("  " + _tally_line(name, tally, result.frames_read))
    proposal = result.proposal()
    mirrored = result.mirrored_only()
    if proposal:
        lines.append(f"  -> zenoh-perception run --dictionary {_flag(proposal)}")
    elif mirrored:
        lines.append(
            f"  found only on the mirrored picture ({', '.join(mirrored)}): the camera or its "
            "driver mirrors the frames; turn mirroring off there (a mirrored marker reads as no id)"
        )
    else:
        lines.append(
            "  no marker of any OpenCV dictionary found: markers may be too small (under about "
            "10 px a side), cut by the image border, blurred, or not ArUco/AprilTag markers"
        )
    return "\n".join(lines)


def _flag(dictionaries: Sequence[str]) -> str:
    joined = ",".join(dictionaries)
    return joined if len(dictionaries) == 1 else f"'{joined}'"


def _tally_line(name: str, tally: FamilyTally, frames_read: int) -> str:
    ids = _id_ranges(sorted(tally.ids))
    low, high = min(tally.sides), max(tally.sides)
    side = f"{low:.0f} px" if round(low) == round(high) else f"{low:.0f}-{high:.0f} px"
    seen = "" if frames_read == 1 else f" in {tally.frames} of {frames_read} frames"
    doubt = ""
    if frames_read > 1 and tally.frames == 1:
        doubt = " (one frame only: perhaps a look-alike)"
    label = smallest_dictionary(name, tally.ids)
    return f"{label:<22} {tally.tags} tags, ids {ids}{seen}, {side}{doubt}"


def _id_ranges(ids: Sequence[int]) -> str:
    """``[1, 2, 3, 7]`` as ``1-3, 7``."""
    runs: list[list[int]] = []
    for tag_id in ids:
        if runs and tag_id == runs[-1][-1] + 1:
            runs[-1].append(tag_id)
        else:
            runs.append([tag_id])
    return ", ".join(f"{r[0]}" if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in runs)


def main(
    paths: Sequence[Path],
    *,
    max_frames: int = DEFAULT_MAX_FRAMES,
    topic: str | None = None,
    as_json: bool = False,
    out: TextIO = sys.stdout,
) -> int:
    """Probe every path; 0 when some dictionary was found in every file, 1 otherwise.

    Raises:
        ReplayError: a path cannot be read as a replay source.

    """
    found_everywhere = True
    for path in paths:
        result = probe(path, max_frames=max_frames, topic=topic)
        found_everywhere &= bool(result.proposal())
        print(json.dumps(result.as_dict()) if as_json else format_probe(result), file=out)
        out.flush()
    return 0 if found_everywhere else 1
