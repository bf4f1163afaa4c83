"""The veto's thresholds as the threshold study varies them (:data:`RULES`), and the service
detector's proposals on a labelled corpus (:func:`collect`), each with every number the rules
compare and whether its id is true; what tools/thresholds.py and tools/cell_sizes.py study."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Final, Literal

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.regions import seen_again
from zenoh_perception.detect.rules import (
    Measures,
    Thresholds,
    dark_ring,
    local_quiet_min,
    quiet_small,
    quiet_waived,
    strokes_read,
    typical_quiet,
    veto_reasons,
)
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import Verifier, measure
from zenoh_perception.pipeline import TagFinder
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import Frame
from zenoh_perception_bench.footage import data_folder, frames
from zenoh_perception_bench.manifest import TooLargeError, load_manifest
from zenoh_perception_bench.runners import BGRA8
from zenoh_perception_bench.scoring import Labels

DEFAULT_DICTIONARY: Final = "DICT_4X4_50"
CURRENT: Final = Thresholds()


@dataclass(frozen=True, slots=True)
class Rule:
    """One threshold: the :class:`Thresholds` field, the constant of rules.py, the veto
    reason it gives, and on which side it vetoes: ``upper``, a value above the threshold
    (at or above for a rule's gate), ``lower``, a value below it."""

    field: str
    constant: str
    reason: str
    #: the rule's condition this threshold is part of (two thresholds share one: QUIET_MIN
    #: and QUIET_LOCAL_MIN, STROKES_MAX and its gate)
    condition: str
    bound: Literal["upper", "lower"]
    #: The value this threshold is compared with on a detection, with the other thresholds
    #: at ``thresholds``; None when, with those, no value of this one vetoes the detection.
    value: Callable[[Measures, Thresholds], float | None]


#: Every threshold of the veto's rules (detect/rules.py), in the order the rules are checked.
RULES: Final = (
    Rule(
        "min_px_per_cell",
        "MIN_PX_PER_CELL",
        "resolution",
        "resolution",
        "lower",
        lambda m, t: m.px_per_cell,
    ),
    Rule(
        "quiet_min",
        "QUIET_MIN",
        "quiet_zone",
        "quiet below",
        "lower",
        lambda m, t: (
            m.quiet if m.quiet_local < local_quiet_min(m, t) and not quiet_waived(m, t) else None
        ),
    ),
    Rule("quiet_max", "QUIET_MAX", "quiet_zone", "quiet above", "upper", lambda m, t: m.quiet),
    Rule(
        "quiet_local_min",
        "QUIET_LOCAL_MIN",
        "quiet_zone",
        "quiet below",
        "lower",
        lambda m, t: (
            m.quiet_local
            if m.quiet < t.quiet_min and not quiet_small(m, t) and not quiet_waived(m, t)
            else None
        ),
    ),
    Rule(
        "quiet_local_min_small",
        "QUIET_LOCAL_MIN_SMALL",
        "quiet_zone",
        "quiet below",
        "lower",
        lambda m, t: (
            m.quiet_local
            if m.quiet < t.quiet_min and quiet_small(m, t) and not quiet_waived(m, t)
            else None
        ),
    ),
    Rule(
        "quiet_small_px_per_cell",
        "QUIET_SMALL_PX_PER_CELL",
        "quiet_zone",
        "quiet below",
        "upper",
        # a marker whose local level lies between the two bounds: vetoed from the gate up
        lambda m, t: (
            m.px_per_cell
            if m.quiet < t.quiet_min
            and t.quiet_local_min_small <= m.quiet_local < t.quiet_local_min
            and not quiet_waived(m, t)
            else None
        ),
    ),
    Rule(
        "quiet_waiver_px_per_cell",
        "QUIET_WAIVER_PX_PER_CELL",
        "quiet_zone",
        "quiet below",
        "lower",
        lambda m, t: (
            m.px_per_cell
            if dark_ring(m, t) and m.margin is not None and m.margin >= t.quiet_waiver_bits
            else None
        ),
    ),
    Rule(
        "quiet_waiver_bits",
        "QUIET_WAIVER_BITS",
        "quiet_zone",
        "quiet below",
        "lower",
        lambda m, t: (
            m.margin if dark_ring(m, t) and m.px_per_cell >= t.quiet_waiver_px_per_cell else None
        ),
    ),
    Rule(
        "border_light_max",
        "BORDER_LIGHT_MAX",
        "border",
        "border",
        "upper",
        lambda m, t: m.border_light,
    ),
    Rule("grid_ratio_max", "GRID_RATIO_MAX", "grid", "grid", "upper", lambda m, t: m.grid_ratio),
    Rule(
        "strokes_max",
        "STROKES_MAX",
        "strokes",
        "strokes",
        "upper",
        lambda m, t: m.strokes if strokes_read(m, t) else None,
    ),
    Rule(
        "strokes_min_px_per_cell",
        "STROKES_MIN_PX_PER_CELL",
        "strokes",
        "strokes",
        "upper",
        lambda m, t: m.px_per_cell if m.strokes > t.strokes_max else None,
    ),
    Rule(
        "margin_min_bits",
        "MARGIN_MIN_BITS",
        "margin",
        "margin",
        "lower",
        lambda m, t: None if m.margin is None or typical_quiet(m) else m.margin,
    ),
)


def with_changes(thresholds: Thresholds, **changes: float) -> Thresholds:
    values = {f.name: getattr(thresholds, f.name) for f in fields(thresholds)}
    return Thresholds(**{**values, **changes})


def vetoes(rule: Rule, measures: Measures, thresholds: Thresholds) -> bool:
    """Whether ``rule``'s threshold alone (the others at ``thresholds``) vetoes a detection
    of ``measures``."""
    value = rule.value(measures, thresholds)
    if value is None:
        return False
    limit = float(getattr(thresholds, rule.field))
    if rule.field == "strokes_min_px_per_cell":
        return strokes_read(measures, thresholds)  # at or above the gate: the same product
    if rule.field == "quiet_small_px_per_cell":
        return not quiet_small(measures, thresholds)
    return value > limit if rule.bound == "upper" else value < limit


@dataclass(frozen=True, slots=True)
class Proposal:
    """One marker OpenCV proposed on a read frame."""

    detection: Detection
    truth: bool | None  # its id labelled there; None: unlabelled on a frame with unread markers
    measures: Measures
    #: the proposals of the stream's previous read (:attr:`Read.previous`) it is the same
    #: marker as (:func:`~zenoh_perception.detect.regions.seen_again`), by index
    before: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Read:
    """One frame read in one dictionary, with at least one proposal."""

    repo: str
    dictionary: str
    labels: Labels
    proposals: tuple[Proposal, ...]
    #: the stream's read before this one, when the verifier's memory carries over to it
    #: (the same video, same frame size, no read with proposals in between), by index
    previous: int | None = None


def truth(tag_id: int, labels: Labels) -> bool | None:
    """True when ``tag_id`` is labelled, False when not and nothing unread is on the frame,
    None when it may be one of the frame's unread markers."""
    if tag_id in labels.markers:
        return True
    return None if labels.unknown_markers > 0 else False


def _finder(settings: Settings, dictionary: str) -> tuple[TagFinder, Verifier]:
    """The service's detector for one stream as the dataset bench builds it, and a verifier
    of its dictionary (whose ``check`` keeps no memory) to compare the replay with."""
    detection = settings.detection
    detector = make_detector(
        detection.detector,
        dictionary,
        full_scan_period=detection.full_scan_period,
        second_look=detection.second_look,
    )
    verifier = Verifier(dictionary)
    finder = TagFinder(
        detector,
        detection.min_tag_side_px,
        verifier if detection.verify else None,
        detection.confirm_frames,
    )
    return finder, verifier


def collect(
    manifest: Path,
    data: Path | None = None,
    *,
    max_video_frames: int = 600,
    settings: Settings | None = None,
    log: Callable[[str], None] | None = None,
) -> tuple[list[Read], int]:
    """Every read of the corpus with its proposals, and how many proposals the replay under
    the current constants judged otherwise than the service's verifier (0 expected)."""
    settings = settings if settings is not None else Settings()
    items = load_manifest(manifest)
    folder = data_folder(manifest, data)
    raw = json.loads(manifest.read_text(encoding="utf-8"))["items"]
    repos = {str(r["name"]): str(r.get("repo", "unknown")) for r in raw}
    # as bench --dataset reads them: a negative in every dictionary of the labelled items
    dictionaries = sorted({i.dictionary for i in items if not i.negative}) or [DEFAULT_DICTIONARY]
    finders: dict[str, tuple[TagFinder, Verifier]] = {}
    last: dict[str, tuple[int, tuple[int, ...]]] = {}  # stream -> its last read, frame shape
    reads: list[Read] = []
    mismatches = 0
    for number, item in enumerate(items, 1):
        if log is not None:
            log(f"[{number}/{len(items)}] {item.name}")
        tested = dictionaries if item.negative else [item.dictionary]
        videos = item.kind != "image"
        try:
            for image in frames(item, folder, max_video_frames, settings.limits.max_frame_pixels):
                for dictionary in tested:
                    # a video's frames are one stream; each still is read afresh, with no
                    # read before it, as the dataset bench reads it
                    stream = f"{item.name}:{dictionary}" if videos else None
                    if stream is None:
                        finder, verifier = _finder(settings, dictionary)
                    else:
                        if stream not in finders:
                            finders[stream] = _finder(settings, dictionary)
                        finder, verifier = finders[stream]
                    # TagFinder.find up to its screen: the detector's read, then the second look
                    # the service takes after the frame's tag, where it takes one
                    gray, found, _ = finder.detect(Frame(image, BGRA8, None, "tool", None))
                    if finder.judges_one_by_one:
                        found += finder.look_again()
                    if not found:
                        continue
                    before = last.get(stream) if stream is not None else None
                    previous = before[0] if before is not None and before[1] == gray.shape else None
                    shown = reads[previous].proposals if previous is not None else ()
                    proposals = []
                    for detection in found:
                        measures = measure(gray, detection, dictionary)
                        replayed = veto_reasons(measures, CURRENT)
                        if (replayed[0] if replayed else None) != verifier.check(gray, detection):
                            mismatches += 1
                        again = tuple(
                            k for k, p in enumerate(shown) if seen_again(detection, p.detection)
                        )
                        proposals.append(
                            Proposal(detection, truth(detection.tag_id, item), measures, again)
                        )
                    if stream is not None:
                        last[stream] = (len(reads), gray.shape)
                    reads.append(
                        Read(repos[item.name], dictionary, item, tuple(proposals), previous)
                    )
        except TooLargeError:
            continue  # refused by the bench and the service alike
    return reads, mismatches
