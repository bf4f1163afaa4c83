"""The range figure of the generated bench: how far away a 20 cm DICT_4X4_50 tag is still found.

At each distance of :data:`DISTANCES_M`, ``frames`` HD720 frames of the scene generator with
one 20 cm tag (random place, turned up to 30°, the generator's realistic effects) go to
OpenCV's default, to OpenCV's best setting (shown, not judged) and to the service's detector
(the service's veto included). A distance is
reached when the tag is found in at least :data:`FOUND_SHARE` of its frames; the range is the
furthest distance reached with every nearer one reached too.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from zenoh_perception.detect.factory import make_detector
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.runners import BEST, DICTIONARY, Baseline, Best, Project, rotation
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator

#: Distances measured, metres.
DISTANCES_M: Final = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 14.0, 16.0)
#: The tag's side, metres.
TAG_M: Final = 0.2
#: Share of a distance's frames in which the tag must be found.
FOUND_SHARE: Final = 0.9
RESOLUTION: Final = "HD720"


def reach(found: dict[float, float], share: float = FOUND_SHARE) -> float:
    """The furthest distance whose share found, and every nearer one's, is at least
    ``share`` (0 when the nearest already is not)."""
    furthest = 0.0
    for distance in sorted(found):
        if found[distance] < share:
            break
        furthest = distance
    return furthest


def range_report(
    frames: int,
    seed: int,
    *,
    distances: Sequence[float] = DISTANCES_M,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Per distance the share of frames in which each detector found the tag, and each
    detector's range (metres)."""
    scenes = SceneGenerator(CameraModel.named(RESOLUTION), seed=seed, effects=Effects.realistic())
    runners: dict[str, Baseline | Project] = {
        "opencv": Baseline(DICTIONARY),
        BEST: Best(DICTIONARY),
        "service": Project(DICTIONARY, make_detector("opencv", DICTIONARY)),
    }
    shares: dict[str, dict[float, float]] = {name: {} for name in runners}
    for distance in distances:
        counts = dict.fromkeys(runners, 0)
        for index in range(frames):
            scene = scenes.random_scene(
                1, size_m=(TAG_M, TAG_M), distance_m=(distance, distance), max_tilt_deg=30.0
            )
            for name in rotation(list(runners), index):
                ids = {d.tag_id for d in runners[name].run(scene.image)[0]}
                counts[name] += int(bool(set(scene.ids) & ids))
            tick(progress, "range")
        for name in runners:
            shares[name][distance] = counts[name] / frames
    return {
        "tag_m": TAG_M,
        "resolution": RESOLUTION,
        "frames_per_distance": frames,
        "found_share": {name: {str(d): s for d, s in by.items()} for name, by in shares.items()},
        "range_m": {name: reach(by) for name, by in shares.items()},
    }
