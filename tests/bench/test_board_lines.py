"""Corner residuals from a ChArUco board's rows: straight rows give none, a corner off its row
shows."""

from __future__ import annotations

import numpy as np
import pytest

from zenoh_perception_bench.board_lines import line_residuals, row_residuals


def _board(rows: int) -> dict[int, np.ndarray]:
    """Markers of 20 px, four a row on alternate squares of 30 px, rows tilted 0.1 rad."""
    turn = np.array([[np.cos(0.1), -np.sin(0.1)], [np.sin(0.1), np.cos(0.1)]])
    square = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0]])
    return {
        4 * row + k: (square + np.array([60.0 * k + 30.0 * (row % 2), 30.0 * row])) @ turn.T + 100.0
        for row in range(rows)
        for k in range(4)
    }


def test_points_on_a_line_have_no_residual() -> None:
    points = np.array([[0.0, 1.0], [2.0, 2.0], [4.0, 3.0], [10.0, 6.0]])
    assert max(line_residuals(points)) == pytest.approx(0.0, abs=1e-9)


def test_a_board_s_rows_are_straight_and_a_corner_off_its_row_shows() -> None:
    corners = _board(3)
    # three rows, two lines each, eight corners a line
    residuals = row_residuals(corners)
    assert len(residuals) == 3 * 2 * 8
    assert max(residuals) == pytest.approx(0.0, abs=1e-9)
    corners[5] = corners[5] + np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.8]])
    assert max(row_residuals(corners)) > 0.5


def test_a_row_of_fewer_than_three_markers_is_left_out() -> None:
    corners = _board(2)
    del corners[5], corners[6]
    assert len(row_residuals(corners)) == 2 * 8  # the first row's two lines only
