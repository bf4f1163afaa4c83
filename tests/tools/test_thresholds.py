"""tools/thresholds.py: the fit, the replay and the leave-one-repository-out sums, on small
synthetic proposals (no corpus)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

from tools.proposals import CURRENT, RULES, Proposal, Read, truth, vetoes
from tools.thresholds import (
    band_rows,
    fit,
    fitted,
    format_bands,
    leave_one_out,
    nearest_true,
    replay,
    rule_rows,
)
from zenoh_perception.detect.rules import GRID_RATIO_MAX, Measures
from zenoh_perception.detect.types import Detection

RULE = {rule.field: rule for rule in RULES}
#: A printed marker's numbers: no rule near its threshold, the margin rule not applied.
CLEAN = Measures(
    shortest_side_px=60.0,
    cells_across=6,
    quiet=1.0,
    quiet_local=1.0,
    border_light=0.0,
    grid_ratio=1.0,
    strokes=0.05,
    margin=5.0,
)


@dataclass(frozen=True)
class _Labels:
    markers: dict[int, int]
    unknown_markers: int = 0
    out_of_view: frozenset[int] = frozenset()


def _proposal(
    tag_id: int, true: bool | None, before: tuple[int, ...] = (), **changes: Any
) -> Proposal:
    corners = np.array([[0, 0], [60, 0], [60, 60], [0, 60]], np.float32)
    return Proposal(Detection(tag_id, corners), true, replace(CLEAN, **changes), before)


def _read(repo: str, *proposals: Proposal, dictionary: str = "DICT_4X4_50") -> Read:
    return Read(repo, dictionary, _Labels({1: 1}), proposals)


def test_the_fit_keeps_the_constants_ratio_to_the_nearest_true_tag() -> None:
    # 2.5 sits 2.5 / 1.5 above the corpus's nearest true tag: the same above the training's
    assert fitted(2.5, 1.5, 1.2) == pytest.approx(2.0)
    assert fitted(0.5, 1.25, 2.5) == pytest.approx(1.0)  # a lower bound moves up
    assert fitted(2.5, 1.5, 1.5) == 2.5  # the same tag: the constant exactly
    assert fitted(2.5, None, 1.2) == 2.5  # no true tag reaches the rule: it stays
    assert fitted(2.5, 1.5, None) == 2.5
    assert fitted(0.35, 0.0, 0.1) == 0.35  # no ratio to a value of 0
    assert fitted(0.35, 0.25, -0.1) == 0.35
    assert fitted(2.5, 1.5, 1.2, margin=False) == 1.2  # the tightest that keeps 1.2
    assert fitted(2.5, None, 1.2, margin=False) == 2.5
    everything = [
        _proposal(1, True, shortest_side_px=7.0),
        _proposal(1, True, shortest_side_px=8.0),
    ]
    nearest_all = {rule.field: nearest_true(rule, everything) for rule in RULES}
    # a hair under 7 / 6 px a cell, which the product with the 6 cells might round past
    limits = fit(everything, nearest_all, RULES, margin=False)
    assert 7.0 / 6.0 * (1 - 1e-6) < limits.min_px_per_cell < 7.0 / 6.0
    assert replay([_read("a", *everything)], limits) == [[True, True]]


def test_the_nearest_true_tag_is_on_the_rules_veto_side_and_false_ids_do_not_count() -> None:
    proposals = [
        _proposal(1, True, grid_ratio=1.2),
        _proposal(1, True, grid_ratio=1.5),
        _proposal(2, False, grid_ratio=2.0),
        _proposal(2, None, grid_ratio=2.2),
        _proposal(1, True, shortest_side_px=9.0),
    ]
    assert nearest_true(RULE["grid_ratio_max"], proposals) == 1.5  # vetoes above: the largest
    assert nearest_true(RULE["min_px_per_cell"], proposals) == 1.5  # below: the smallest, 9 / 6
    assert nearest_true(RULE["quiet_local_min"], proposals) is None  # quiet never under 0.35


def test_a_gated_threshold_sees_only_the_tags_its_gate_lets_through() -> None:
    dark_ring = replace(CLEAN, quiet=0.3, quiet_local=0.7)
    assert RULE["quiet_local_min"].value(dark_ring, CURRENT) == 0.7
    assert RULE["quiet_min"].value(dark_ring, CURRENT) is None  # locally light: never vetoed
    assert RULE["quiet_min"].value(replace(dark_ring, quiet_local=0.4), CURRENT) == 0.3
    stroked = replace(CLEAN, strokes=0.6, shortest_side_px=9.0)  # 1.5 px a cell, under the gate
    assert RULE["strokes_max"].value(stroked, CURRENT) is None
    assert RULE["strokes_min_px_per_cell"].value(stroked, CURRENT) == 1.5
    assert not vetoes(RULE["strokes_min_px_per_cell"], stroked, CURRENT)
    assert vetoes(RULE["strokes_min_px_per_cell"], replace(stroked, shortest_side_px=12.0), CURRENT)
    typical = replace(CLEAN, margin=0.1)  # quiet 1.0: a printed marker's surround
    assert RULE["margin_min_bits"].value(typical, CURRENT) is None
    assert RULE["margin_min_bits"].value(replace(typical, quiet=1.5), CURRENT) == 0.1


def test_fit_moves_only_the_thresholds_the_training_tags_say() -> None:
    everything = [_proposal(1, True, grid_ratio=1.5), _proposal(1, True, grid_ratio=1.2)]
    nearest_all = {rule.field: nearest_true(rule, everything) for rule in RULES}
    limits = fit(everything[1:], nearest_all, RULES)
    assert limits.grid_ratio_max == pytest.approx(GRID_RATIO_MAX / 1.5 * 1.2)
    assert replace(limits, grid_ratio_max=CURRENT.grid_ratio_max) == CURRENT


def test_the_replay_keeps_a_marker_kept_on_the_frame_before_unread() -> None:
    first = _read("a", _proposal(1, True), _proposal(2, False, grid_ratio=3.0))
    # the same two markers again, now both beyond the grid bound
    again = Read(
        "a",
        "DICT_4X4_50",
        _Labels({1: 1}),
        (_proposal(1, True, (0,), grid_ratio=3.0), _proposal(2, False, (1,), grid_ratio=3.0)),
        previous=0,
    )
    assert replay([first, again], CURRENT) == [[True, False], [True, False]]
    # the tighter thresholds on repository "b" only: "a" replays with the constants
    assert replay([first, again], replace(CURRENT, grid_ratio_max=0.5), "b") == [
        [True, False],
        [True, False],
    ]
    assert replay([first, again], replace(CURRENT, grid_ratio_max=0.5)) == [
        [False, False],
        [False, False],
    ]


def test_leave_one_out_sums_what_each_held_out_repository_loses_and_keeps() -> None:
    reads = [
        # "a" holds the corpus's nearest true tag (grid 2.0: the constant 2.5 is 1.25 times it)
        _read("a", _proposal(1, True, grid_ratio=2.0), _proposal(2, False, grid_ratio=2.2)),
        _read(
            "b",
            _proposal(1, True, grid_ratio=1.0),
            _proposal(2, False, grid_ratio=3.0),
            dictionary="DICT_6X6_250",
        ),
    ]
    held = {h.repo: h for h in leave_one_out(reads)}
    # without "a" the bound is 1.25 x 1.0: a's true tag is lost, its false id vetoed
    assert held["a"].moved == {"grid_ratio_max": pytest.approx(1.25)}
    assert (held["a"].opencv.found, held["a"].current.found, held["a"].fitted.found) == (1, 1, 0)
    assert (held["a"].current.false_ids, held["a"].fitted.false_ids) == (1, 0)
    assert (held["a"].current.false_default, held["a"].fitted.false_default) == (1, 0)
    # without "b" the nearest true tag is a's own: the constants, and b's false id vetoed
    assert held["b"].moved == {}
    assert (held["b"].current.found, held["b"].fitted.found) == (1, 1)
    assert (held["b"].opencv.false_ids, held["b"].fitted.false_ids) == (1, 0)
    assert held["b"].opencv.false_default == 0  # read in DICT_6X6_250
    # with no margin the bound is the training's nearest true tag: 1.0 without "a", 2.0
    # without "b"; a's true tag and false id are then both lost, b's kept and vetoed
    assert (held["a"].bare.found, held["a"].bare.false_ids) == (0, 0)
    assert (held["b"].bare.found, held["b"].bare.false_ids) == (1, 0)


def test_the_rule_rows_count_the_false_ids_each_threshold_vetoes_and_vetoes_alone() -> None:
    reads = [
        _read(
            "a",
            _proposal(1, True, grid_ratio=1.5),
            _proposal(2, False, grid_ratio=3.0),
            _proposal(3, False, grid_ratio=3.0, border_light=0.5),
            _proposal(4, None, grid_ratio=3.0),  # beside an unread marker: not false
        )
    ]
    rows = {row.constant: row for row in rule_rows(reads)}
    grid = rows["GRID_RATIO_MAX"]
    assert (grid.nearest_true, grid.nearest_repo) == (1.5, "a")
    assert grid.ratio == pytest.approx(2.5 / 1.5)
    assert grid.distance == pytest.approx(1.0)
    assert (grid.false_vetoed, grid.false_alone) == (2, 1)
    assert (rows["BORDER_LIGHT_MAX"].false_vetoed, rows["BORDER_LIGHT_MAX"].false_alone) == (1, 0)
    assert rows["QUIET_LOCAL_MIN"].nearest_true is None


def test_two_thresholds_of_one_condition_veto_together_and_count_alone() -> None:
    dark: dict[str, Any] = {"quiet": 0.1, "quiet_local": 0.2}  # under both bounds
    reads = [_read("a", _proposal(2, False, **dark), _proposal(3, False, grid_ratio=3.0, **dark))]
    rows = {row.constant: row for row in rule_rows(reads)}
    for name in ("QUIET_MIN", "QUIET_LOCAL_MIN"):
        assert (rows[name].false_vetoed, rows[name].false_alone) == (2, 1)
    assert (rows["GRID_RATIO_MAX"].false_vetoed, rows["GRID_RATIO_MAX"].false_alone) == (1, 0)


def test_truth_is_the_label_or_unknown_beside_an_unread_marker() -> None:
    assert truth(1, _Labels({1: 1})) is True
    assert truth(2, _Labels({1: 1})) is False
    assert truth(2, _Labels({1: 1}, unknown_markers=1)) is None


def test_each_rule_is_studied_per_band_of_pixels_a_cell_and_fitted_leaving_a_repository_out() -> (
    None
):
    # grid ratios of true tags: 2.0 at 2.2 px a cell (repository a), 1.6 at 2.3 (b) and 1.2 at
    # 8 px a cell (a); a false id at 2.1 px a cell the grid rule vetoes
    reads = [
        _read(
            "a",
            _proposal(1, True, shortest_side_px=2.2 * 6, grid_ratio=2.0),
            _proposal(1, True, grid_ratio=1.2, shortest_side_px=48.0),
        ),
        _read("b", _proposal(1, True, shortest_side_px=2.3 * 6, grid_ratio=1.6)),
        _read("b", _proposal(2, False, shortest_side_px=2.1 * 6, grid_ratio=3.0)),
    ]
    rows = {(r.constant, r.low): r for r in band_rows(reads)}
    small = rows["GRID_RATIO_MAX", 2.0]
    assert (small.true_reaching, small.nearest_true, small.nearest_repo) == (2, 2.0, "a")
    assert (small.true_vetoed, small.false_vetoed) == (0, 1)
    # fitted without a, the band's bound is 1.6 x 2.5 / 2.0 = 2.0: a's tag at 2.0 stays
    assert small.lost_out_of_sample == 0
    large = rows["GRID_RATIO_MAX", 6.0]
    assert (large.true_reaching, large.nearest_true, large.false_vetoed) == (1, 1.2, 0)
    # the thresholds that are themselves a size are not studied per size
    assert not any(r.constant == "MIN_PX_PER_CELL" for r in rows.values())
    assert "| GRID_RATIO_MAX | 2-2.5 | 2.5 | 2 | 2 (a) | 0 | 0 | 1 |" in format_bands(
        list(rows.values())
    )
