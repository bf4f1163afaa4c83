"""The generated frame sets: every set, its size, and the same frames for the same seed."""

from __future__ import annotations

import io

import numpy as np

from zenoh_perception.resolutions import RESOLUTIONS as SIZES
from zenoh_perception_bench.framesets import RESOLUTIONS, VIDEO_RESOLUTION, Plan, frame_sets
from zenoh_perception_bench.progress import Progress

TINY = Plan(frames=2, video_frames=3, distractor_frames=1, throughput_s=0.1, e2e_passes=1)


def test_every_set_has_its_frames_at_its_resolution() -> None:
    sets = frame_sets(TINY, None)
    assert [s.name for s in sets] == [
        *RESOLUTIONS,
        "video",
        "distractors",
        "real-camera",
        "real-camera video",
    ]
    sizes = {s.name: len(s.scenes) for s in sets}
    assert sizes == {
        **dict.fromkeys(RESOLUTIONS, 2),
        "video": 3,
        "distractors": 1,
        "real-camera": 2,
        "real-camera video": 3,
    }
    for frame_set in sets:
        assert frame_set.video == frame_set.name.endswith("video")
        width, height = SIZES[frame_set.resolution]
        assert all(s.image.shape == (height, width, 4) for s in frame_set.scenes)
        if frame_set.name not in RESOLUTIONS:
            assert frame_set.resolution == VIDEO_RESOLUTION
    distractors = next(s for s in sets if s.name == "distractors")
    assert len(distractors.scenes[0].markers) == 1  # one tag among the look-alikes


def test_the_same_seed_makes_the_same_frames_and_counts_progress() -> None:
    progress = Progress(100, stream=io.StringIO())
    first = frame_sets(TINY, progress)
    second = frame_sets(TINY, None)
    assert progress.done == sum(len(s.scenes) for s in first)
    for a, b in zip(first, second, strict=True):
        assert all(
            np.array_equal(x.image, y.image) for x, y in zip(a.scenes, b.scenes, strict=True)
        )
