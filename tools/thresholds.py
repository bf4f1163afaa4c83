"""The veto's thresholds against the real corpus, split by repository.

``python -m tools.thresholds [--dataset corpus/manifest.json] [--json PATH] [--records PATH]``

Runs the service's detector (OpenCV's default proposals, and the second look's where the
settings take it: the detector the default settings name, built by the package's factory as
the dataset bench builds it, fed as it feeds it) over every item of the
manifest: stills, videos' frames as ``bench --dataset`` samples them, and each negative in every
dictionary the manifest uses. Each proposal is *true* when its id is labelled on its frame and
*false* when the frame holds no such id and no unread marker (else it is left out of the fit),
and gets every number the veto's rules compare (:func:`~zenoh_perception.detect.verify.measure`)
and the repository its item came from (the manifest's ``repo``).

For every threshold (:data:`RULES`): its current value, the value at the nearest true tag on
the whole corpus (each threshold with the others at their current values), the distance in
the rule's units and as a ratio, and the false ids it vetoes (of which no other rule's
condition vetoes: "alone"; QUIET_MIN and QUIET_LOCAL_MIN form one condition, as STROKES_MAX
and its gate do).

Leave one repository out: for each repository R, every threshold is fitted on the true tags of
the other repositories (:func:`fitted`: the nearest true tag there, times the ratio the current
constant keeps to the nearest true tag of the whole corpus), the whole veto is replayed with the
fitted thresholds (:func:`replay`: as the service's verifier runs, a marker kept on a stream's
frame before and seen again kept without being read), and R's frames are scored as
``bench --dataset`` scores them; the sums over R: true tags lost and false ids kept (all, and
in DICT_4X4_50), beside the same with the current constants and with a fit that keeps no
margin (each threshold a hair beyond the training's nearest true tag): what the margin buys.
Only R's reads are scored, and only they get the fitted thresholds.

Exit status 0; 1 when the replay under the current constants disagrees with the service's
verifier on a proposal (the study would then not be about the service's veto).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.regions import seen_again
from zenoh_perception.detect.rules import (
    Measures,
    Thresholds,
    dark_ring,
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
from zenoh_perception_bench.scoring import Labels, Score

#: The dictionary whose false ids the study reports apart (the service's default).
DEFAULT_DICTIONARY: Final = "DICT_4X4_50"
CURRENT: Final = Thresholds()
#: The fit without a margin puts a threshold this share beyond the nearest true tag.
BARE_EPSILON: Final = 1e-9


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
            m.quiet if m.quiet_local < t.quiet_local_min and not quiet_waived(m, t) else None
        ),
    ),
    Rule("quiet_max", "QUIET_MAX", "quiet_zone", "quiet above", "upper", lambda m, t: m.quiet),
    Rule(
        "quiet_local_min",
        "QUIET_LOCAL_MIN",
        "quiet_zone",
        "quiet below",
        "lower",
        lambda m, t: m.quiet_local if m.quiet < t.quiet_min and not quiet_waived(m, t) else None,
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


def _with(thresholds: Thresholds, **changes: float) -> Thresholds:
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
    return value > limit if rule.bound == "upper" else value < limit


# -- what the corpus gives -------------------------------------------------------------------


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
    detector = make_detector(
        settings.detector,
        dictionary,
        full_scan_period=settings.full_scan_period,
        second_look=settings.second_look,
    )
    verifier = Verifier(dictionary)
    finder = TagFinder(
        detector,
        settings.min_tag_side_px,
        verifier if settings.verify else None,
        settings.confirm_frames,
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
            for image in frames(item, folder, max_video_frames, settings.max_frame_pixels):
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


# -- the fit and the replay ------------------------------------------------------------------


def nearest_true(
    rule: Rule, proposals: Iterable[Proposal], thresholds: Thresholds = CURRENT
) -> float | None:
    """The value of ``rule`` at the true tag nearest its veto side (the largest value of an
    ``upper`` rule, the smallest of a ``lower`` one), the other thresholds at
    ``thresholds``; None when no true tag can be vetoed by it."""
    values = [rule.value(p.measures, thresholds) for p in proposals if p.truth is True]
    present = [v for v in values if v is not None]
    if not present:
        return None
    return max(present) if rule.bound == "upper" else min(present)


def fitted(
    current: float, nearest_all: float | None, nearest_train: float | None, *, margin: bool = True
) -> float:
    """The fit: the training repositories' nearest true tag times the ratio the current
    constant keeps to the whole corpus's nearest true tag (the same relative safety margin;
    without ``margin``, the nearest true tag itself: the tightest value that keeps it).
    With no true tag reaching the rule on either, or a value not above 0 (a ratio is then
    meaningless), the current constant stays."""
    if nearest_all is None or nearest_train is None or nearest_all <= 0 or nearest_train <= 0:
        return current
    if not margin:
        return nearest_train
    if nearest_train == nearest_all:
        return current  # the same tag: the constant itself, not its product's rounding
    return current / nearest_all * nearest_train


def fit(
    proposals: Sequence[Proposal],
    nearest_all: dict[str, float | None],
    rules: Sequence[Rule],
    *,
    margin: bool = True,
) -> Thresholds:
    """Every threshold of ``rules`` fitted on ``proposals``' true tags (:func:`fitted`), each
    with the others at their current values."""
    changes = {}
    for rule in rules:
        value = fitted(
            float(getattr(CURRENT, rule.field)),
            nearest_all[rule.field],
            nearest_true(rule, proposals),
            margin=margin,
        )
        if not margin and value != getattr(CURRENT, rule.field):
            # a hair beyond the tag, on the keeping side: a rule that compares a product (the
            # pixels per cell times the cells) or vetoes at its value (a gate) keeps it too
            value *= 1.0 + BARE_EPSILON if rule.bound == "upper" else 1.0 - BARE_EPSILON
        changes[rule.field] = value
    return _with(CURRENT, **changes)


def replay(
    reads: Sequence[Read], thresholds: Thresholds, only: str | None = None
) -> list[list[bool]]:
    """Which proposals the service's verifier keeps, read by read in order, with
    ``thresholds`` on the reads of repository ``only`` (None: every read) and the current
    constants on the others: a proposal the same marker as one kept on the stream's previous
    read is kept unread, any other when no rule vetoes it."""
    kept: list[list[bool]] = []
    for read in reads:
        before = kept[read.previous] if read.previous is not None else []
        limits = thresholds if only is None or read.repo == only else CURRENT
        kept.append(
            [
                any(before[k] for k in p.before) or not veto_reasons(p.measures, limits)
                for p in read.proposals
            ]
        )
    return kept


@dataclass(slots=True)
class Tally:
    """True tags found and false ids over some reads, as ``bench --dataset`` scores them."""

    found: int = 0
    false_ids: int = 0
    false_default: int = 0  # of them in DEFAULT_DICTIONARY

    def add(self, read: Read, kept: Sequence[bool]) -> None:
        score = Score()
        score.add(
            read.labels, [p.detection for p, k in zip(read.proposals, kept, strict=True) if k], 0.0
        )
        self.found += score.found
        self.false_ids += score.false_ids
        if read.dictionary == DEFAULT_DICTIONARY:
            self.false_default += score.false_ids


def tally(reads: Sequence[Read], kept: Sequence[Sequence[bool]], repo: str | None) -> Tally:
    """What the reads of ``repo`` (None: all) score with ``kept``."""
    out = Tally()
    for read, flags in zip(reads, kept, strict=True):
        if repo is None or read.repo == repo:
            out.add(read, flags)
    return out


@dataclass(slots=True)
class Held:
    """One repository left out: the thresholds fitted without it and what they do on it."""

    repo: str
    moved: dict[str, float]  # threshold field -> fitted value, where it differs from current
    opencv: Tally
    current: Tally
    fitted: Tally
    bare: Tally  # fitted without the safety margin (the training's nearest true tags)


def leave_one_out(reads: Sequence[Read], rules: Sequence[Rule] = RULES) -> list[Held]:
    """For each repository, the thresholds fitted on the others' true tags, and R's score
    with none, the current and the fitted thresholds (the veto replayed over every read, so
    that a stream's memory runs as in the service; only R's reads scored)."""
    proposals = [p for r in reads for p in r.proposals]
    nearest_all = {rule.field: nearest_true(rule, proposals) for rule in rules}
    everything = [[True] * len(r.proposals) for r in reads]
    now = replay(reads, CURRENT)
    out: list[Held] = []
    for repo in sorted({r.repo for r in reads}):
        train = [p for r in reads if r.repo != repo for p in r.proposals]
        limits = fit(train, nearest_all, rules)
        moved = {
            f.name: float(getattr(limits, f.name))
            for f in fields(limits)
            if getattr(limits, f.name) != getattr(CURRENT, f.name)
        }
        kept = replay(reads, limits, repo) if moved else now
        bare = replay(reads, fit(train, nearest_all, rules, margin=False), repo)
        out.append(
            Held(
                repo,
                moved,
                tally(reads, everything, repo),
                tally(reads, now, repo),
                tally(reads, kept, repo),
                tally(reads, bare, repo),
            )
        )
    return out


# -- the report ------------------------------------------------------------------------------


@dataclass(slots=True)
class RuleRow:
    """One threshold on the whole corpus."""

    constant: str
    reason: str
    vetoes: str  # "above" or "below"
    current: float
    nearest_true: float | None
    nearest_repo: str | None
    distance: float | None  # |current - nearest_true|, the rule's units
    ratio: float | None  # current / nearest_true
    true_reaching: int  # true tags this threshold can veto (with the others as they are)
    false_vetoed: int
    false_alone: int  # false ids no other rule's condition vetoes


def rule_rows(reads: Sequence[Read], rules: Sequence[Rule] = RULES) -> list[RuleRow]:
    """Each threshold's row on the whole corpus."""
    located = [(r.repo, p) for r in reads for p in r.proposals]
    false = [p for _, p in located if p.truth is False]
    # a false id's vetoing conditions (the two thresholds of one condition veto together)
    by_false = [
        {rule.condition for rule in rules if vetoes(rule, p.measures, CURRENT)} for p in false
    ]
    rows = []
    for rule in rules:
        current = float(getattr(CURRENT, rule.field))
        nearest = nearest_true(rule, (p for _, p in located))
        where = None
        if nearest is not None:
            where = next(
                repo
                for repo, p in located
                if p.truth is True and rule.value(p.measures, CURRENT) == nearest
            )
        rows.append(
            RuleRow(
                constant=rule.constant,
                reason=rule.reason,
                vetoes="above" if rule.bound == "upper" else "below",
                current=current,
                nearest_true=nearest,
                nearest_repo=where,
                distance=None if nearest is None else abs(current - nearest),
                ratio=None if nearest is None or nearest == 0 else current / nearest,
                true_reaching=sum(
                    1
                    for _, p in located
                    if p.truth is True and rule.value(p.measures, CURRENT) is not None
                ),
                false_vetoed=sum(1 for hit in by_false if rule.condition in hit),
                false_alone=sum(1 for hit in by_false if hit == {rule.condition}),
            )
        )
    return rows


def _num(value: float | None, digits: int = 3) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}".rstrip("0").rstrip(".")


def format_report(
    reads: Sequence[Read], rows: Sequence[RuleRow], held: Sequence[Held], mismatches: int
) -> str:
    """The markdown tables."""
    proposals = [p for r in reads for p in r.proposals]
    true = sum(1 for p in proposals if p.truth is True)
    false = sum(1 for p in proposals if p.truth is False)
    lines = [
        f"{len(proposals)} proposals of the service's detector (OpenCV's reads) on {len(reads)}"
        f" reads (a frame in a dictionary) from {len({r.repo for r in reads})} repositories:"
        f" {true} true, {false} false, {len(proposals) - true - false} unlabelled beside"
        " unread markers; replay under"
        f" the constants differs from the service's verifier on {mismatches}.",
        "",
        "| threshold (rule) | vetoes | current | nearest true tag (repository) | distance"
        " | ratio | true tags it can veto | false ids vetoed (alone) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        where = f"{_num(row.nearest_true)} ({row.nearest_repo})" if row.nearest_repo else "none"
        lines.append(
            f"| {row.constant} ({row.reason}) | {row.vetoes} | {_num(row.current)} | {where}"
            f" | {_num(row.distance)} | {_num(row.ratio, 2)} | {row.true_reaching}"
            f" | {row.false_vetoed} ({row.false_alone}) |"
        )
    opencv = Tally()
    current = Tally()
    fitted_sum = Tally()
    bare = Tally()
    for h in held:
        parts = ((opencv, h.opencv), (current, h.current), (fitted_sum, h.fitted), (bare, h.bare))
        for total, part in parts:
            total.found += part.found
            total.false_ids += part.false_ids
            total.false_default += part.false_default
    lines += [
        "",
        "Leave one repository out, summed over the held-out repositories:",
        "",
        f"| thresholds | true tags lost (of {opencv.found}) | false ids kept (of"
        f" {opencv.false_ids}) | in {DEFAULT_DICTIONARY} (of {opencv.false_default}) |",
        "|---|---|---|---|",
        f"| current constants | {opencv.found - current.found} | {current.false_ids}"
        f" | {current.false_default} |",
        f"| fitted without the held-out repository | {opencv.found - fitted_sum.found}"
        f" | {fitted_sum.false_ids} | {fitted_sum.false_default} |",
        f"| the same with no safety margin (the training's nearest true tags)"
        f" | {opencv.found - bare.found} | {bare.false_ids} | {bare.false_default} |",
    ]
    moved = [h for h in held if h.moved or h.bare != h.current]
    if moved:
        lines += [
            "",
            "Held-out repositories where a fit differs from the constants (the others' fit with"
            " the margin is the constants):",
            "",
            "| held out | thresholds fitted without it | true lost: current / fitted / no margin"
            " | false kept: current / fitted / no margin |",
            "|---|---|---|---|",
        ]
        for h in moved:
            names = {f.field: f.constant for f in RULES}
            shown = ", ".join(
                f"{names[k]} {_num(float(getattr(CURRENT, k)))} → {_num(v)}"
                for k, v in h.moved.items()
            )
            shown = shown or "the constants"
            lines.append(
                f"| {h.repo} | {shown} | {h.opencv.found - h.current.found} /"
                f" {h.opencv.found - h.fitted.found} / {h.opencv.found - h.bare.found}"
                f" | {h.current.false_ids} / {h.fitted.false_ids} / {h.bare.false_ids} |"
            )
    return "\n".join(lines)


def _plain(value: Any) -> Any:
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def main(
    manifest: Path,
    data: Path | None = None,
    *,
    max_video_frames: int = 600,
    json_path: Path | None = None,
    records: Path | None = None,
    quiet: bool = False,
) -> int:
    """Collect, fit, replay, print; 1 when the replay disagrees with the verifier."""

    def log(line: str) -> None:
        if not quiet:
            print(line, file=sys.stderr, flush=True)

    if records is not None and records.exists():
        with records.open("rb") as stored:  # written by an earlier run of this tool
            reads, mismatches = pickle.load(stored)  # noqa: S301
    else:
        reads, mismatches = collect(manifest, data, max_video_frames=max_video_frames, log=log)
        if records is not None:
            with records.open("wb") as file:
                pickle.dump((reads, mismatches), file)
    rows = rule_rows(reads)
    held = leave_one_out(reads)
    print(format_report(reads, rows, held, mismatches))
    if json_path is not None:
        report = {
            "manifest": str(manifest),
            "max_video_frames": max_video_frames,
            "mismatches": mismatches,
            "rules": [asdict(row) for row in rows],
            "leave_one_out": [asdict(h) for h in held],
        }
        json_path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(report, indent=2, default=_plain)
        json_path.write_text(text + "\n", encoding="utf-8")
    return 0 if mismatches == 0 else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        prog="python -m tools.thresholds",
        description="The veto's thresholds on the real corpus: nearest true tag, and a fit"
        " left out one repository at a time.",
    )
    parser.add_argument("--dataset", type=Path, default=Path("corpus/manifest.json"))
    parser.add_argument("--data", type=Path, default=None, help="the items' folder")
    parser.add_argument(
        "--max-video-frames", type=int, default=600, help="as bench --dataset (default 600)"
    )
    parser.add_argument("--json", type=Path, default=None, metavar="PATH")
    parser.add_argument(
        "--records",
        type=Path,
        default=None,
        metavar="PATH",
        help="the corpus's proposals kept here (pickle) and read back when it exists, to redo"
        " the analysis without reading the corpus again (by this command only)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    args = parser.parse_args()
    sys.exit(
        main(
            args.dataset,
            args.data,
            max_video_frames=args.max_video_frames,
            json_path=args.json,
            records=args.records,
            quiet=args.quiet,
        )
    )
