"""tools/stalls.py: the boards it measures with."""

from __future__ import annotations

import numpy as np

from tools.stalls import _board_frame, checkerboard
from zenoh_perception.wire.frames import decode_raw_frame


def test_checkerboard_alternates_squares_of_the_given_side() -> None:
    board = checkerboard(40, 20, 10)
    assert board.shape == (20, 40)
    assert set(np.unique(board).tolist()) == {0, 255}
    assert board[0, 0] == 0 and board[0, 10] == 255 and board[10, 0] == 255
    assert (board[:10, :10] == 0).all()


def test_a_board_frame_is_a_mono8_raw_frame_the_service_decodes() -> None:
    frame = _board_frame(64, 32, 8, seq=5)
    decoded = decode_raw_frame(frame.payload, frame.attachment, max_pixels=64 * 32)
    assert (decoded.width, decoded.height, decoded.seq) == (64, 32, 5)
