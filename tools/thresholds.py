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
condition vetoes: "alone"; QUIET_MIN and the local bounds form one condition, as STROKES_MAX
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
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Final

import numpy as np

from tools.proposals import (
    CURRENT,
    DEFAULT_DICTIONARY,
    RULES,
    Proposal,
    Read,
    Rule,
    collect,
    vetoes,
    with_changes,
)
from zenoh_perception.detect.rules import Thresholds, veto_reasons
from zenoh_perception_bench.scoring import Score

#: The fit without a margin puts a threshold this share beyond the nearest true tag.
BARE_EPSILON: Final = 1e-9


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
    return with_changes(CURRENT, **changes)


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


#: The bands of pixels a cell along a marker's shortest side the rules are studied in (1.5-3
#: px a cell is where boards of small markers and far tags live).
CELL_BANDS: Final = ((0.0, 1.5), (1.5, 2.0), (2.0, 2.5), (2.5, 3.0), (3.0, 4.0), (4.0, 6.0))
#: The thresholds that are themselves a size (pixels a cell): their band is what they decide.
SIZE_GATES: Final = frozenset(
    {
        "min_px_per_cell",
        "quiet_small_px_per_cell",
        "quiet_waiver_px_per_cell",
        "strokes_min_px_per_cell",
    }
)


@dataclass(slots=True)
class BandRow:
    """One threshold in one band of pixels a cell (from ``low``, below ``high``)."""

    constant: str
    low: float
    high: float
    current: float
    true_reaching: int  # true tags in the band the threshold can veto (the others as they are)
    nearest_true: float | None
    nearest_repo: str | None
    true_vetoed: int  # true tags in the band the threshold vetoes now
    #: true tags in the band lost when its bound there is fitted leaving their repository
    #: out (the training's nearest true tag in the band, the constant's margin kept)
    lost_out_of_sample: int
    false_vetoed: int  # false ids in the band the threshold vetoes now


def band_rows(
    reads: Sequence[Read], rules: Sequence[Rule] = RULES, bands: Sequence[tuple[float, float]] = ()
) -> list[BandRow]:
    """Each threshold that is not a size, in each band of pixels a cell (default:
    :data:`CELL_BANDS` and one from 6 up) where a true tag can reach it or it vetoes a false
    id: the nearest true tag there, and a bound fitted per band leaving one repository out."""
    bands = bands or (*CELL_BANDS, (CELL_BANDS[-1][1], float("inf")))
    located = [(r.repo, p) for r in reads for p in r.proposals if p.truth is not None]
    rows = []
    for rule in rules:
        if rule.field in SIZE_GATES:
            continue
        current = float(getattr(CURRENT, rule.field))
        for low, high in bands:
            inside = [(repo, p) for repo, p in located if low <= p.measures.px_per_cell < high]
            true = [
                (repo, p)
                for repo, p in inside
                if p.truth and rule.value(p.measures, CURRENT) is not None
            ]
            false = sum(1 for _, p in inside if not p.truth and vetoes(rule, p.measures, CURRENT))
            if not true and not false:
                continue
            nearest = nearest_true(rule, (p for _, p in true))
            where = next(
                (repo for repo, p in true if rule.value(p.measures, CURRENT) == nearest), None
            )
            lost = 0
            for held in sorted({repo for repo, _ in true}):
                train = nearest_true(rule, (p for repo, p in true if repo != held))
                limits = with_changes(CURRENT, **{rule.field: fitted(current, nearest, train)})
                lost += sum(
                    1 for repo, p in true if repo == held and vetoes(rule, p.measures, limits)
                )
            rows.append(
                BandRow(
                    constant=rule.constant,
                    low=low,
                    high=high,
                    current=current,
                    true_reaching=len(true),
                    nearest_true=nearest,
                    nearest_repo=where,
                    true_vetoed=sum(1 for _, p in true if vetoes(rule, p.measures, CURRENT)),
                    lost_out_of_sample=lost,
                    false_vetoed=false,
                )
            )
    return rows


def format_bands(rows: Sequence[BandRow]) -> str:
    """The per-band table, markdown."""
    lines = [
        "Per band of pixels a cell (shortest side): the nearest true tag, the true tags and"
        " false ids the threshold vetoes there, and the true tags lost with the band's bound"
        " fitted leaving their repository out:",
        "",
        "| threshold | px a cell | current | true tags it can veto | nearest true tag"
        " (repository) | true vetoed | lost out of sample | false ids vetoed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        high = "up" if row.high == float("inf") else _num(row.high)
        where = f"{_num(row.nearest_true)} ({row.nearest_repo})" if row.nearest_repo else "-"
        lines.append(
            f"| {row.constant} | {_num(row.low)}-{high} | {_num(row.current)}"
            f" | {row.true_reaching} | {where} | {row.true_vetoed} | {row.lost_out_of_sample}"
            f" | {row.false_vetoed} |"
        )
    return "\n".join(lines)


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
    bands = band_rows(reads)
    print(format_report(reads, rows, held, mismatches))
    print()
    print(format_bands(bands))
    if json_path is not None:
        report = {
            "manifest": str(manifest),
            "max_video_frames": max_video_frames,
            "mismatches": mismatches,
            "rules": [asdict(row) for row in rows],
            "leave_one_out": [asdict(h) for h in held],
            "bands": [asdict(b) for b in bands],
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
