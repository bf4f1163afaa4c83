"""The coarse first read's agreement study: a near tag's frames answered from it, alike."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tools.coarse_agreement import compare
from zenoh_perception.settings import Settings
from zenoh_perception_bench.scene import render_markers


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _frames() -> list[npt.NDArray[np.uint8]]:
    """A tag 7 growing from 120 to 150 px beside a far tag 3, on HD720."""
    return [
        render_markers(
            1280, 720, [(7, _square(300, 200, 120 + 10 * i)), (3, _square(900, 400, 40))]
        )
        for i in range(4)
    ]


def test_frames_after_the_first_are_answered_from_the_coarse_read_alike() -> None:
    row = compare(_frames(), Settings())
    assert row["frames"] == 4
    assert row["coarse"] == 3  # the first frame has no tag before it
    assert row["differ"] == 0
    assert row["slow"] == 0
    assert row["centre_max_px"] == 0.0
