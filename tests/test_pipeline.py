"""The pipeline keeps no state per frame size: a camera that changes size costs no memory."""

from __future__ import annotations

import tracemalloc

import numpy as np

from zenoh_perception.pipeline import Pipeline
from zenoh_perception.scene import render_markers
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import RawFrameMeta, decode_raw_frame


def _frames(count: int, first: int) -> list[tuple[bytes, bytes]]:
    """``count`` BGRA frames, each of a size no other frame has (from ``first``)."""
    frames = []
    for i in range(count):
        width, height = 320 + 2 * (first + i), 240 + (first + i)
        side = 60.0
        corners = np.array([[40, 40], [40 + side, 40], [40 + side, 40 + side], [40, 40 + side]])
        image = render_markers(width, height, [(5, corners)])
        frames.append((image.tobytes(), RawFrameMeta(width, height).to_msgpack()))
    return frames


def test_frames_of_ever_new_sizes_do_not_grow_memory() -> None:
    pipeline = Pipeline(Settings())
    warm_up, measured = _frames(10, 0), _frames(120, 10)
    tracemalloc.start()
    try:
        for payload, meta in warm_up:
            assert pipeline.process(decode_raw_frame(payload, meta)).selected.tag_id == 5
        before, _peak = tracemalloc.get_traced_memory()
        for payload, meta in measured:
            assert pipeline.process(decode_raw_frame(payload, meta)).selected.tag_id == 5
        after, _peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # A cache of one buffer per frame size would hold 120 frames of 77-140 kB or more each.
    assert after - before < 1 << 20
