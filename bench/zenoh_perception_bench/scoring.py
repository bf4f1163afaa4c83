"""What a detector got right, against a generated scene's truth or a person's labels.

:class:`Tally` scores generated frames (:mod:`zenoh_perception_bench.scene`, exact ground truth):
recall (visible, unoccluded tags found with the right id), false positives (reported tags
that are not a tag there), centre error (pixels, mean of the corners against the truth) and
distance error (solvePnP on the reported corners with the scene's intrinsics and tag size).

:class:`Score` scores labelled pictures and videos: a reported id is *found* when the labels
hold it (at most as many times as labelled), else it is a *false id*; markers a person saw but
could not read absorb as many unlabelled ids (*unverified*). Found markers and false ids are
also counted by their mean side in pixels (:func:`size_bucket`), and found and labelled markers
by id (what was *missed*).

Both keep every detection time, in milliseconds.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

import numpy as np

from zenoh_perception.detect.types import Detection
from zenoh_perception.tags.geometry import mean_side
from zenoh_perception.tags.pose import Intrinsics, estimate_pose
from zenoh_perception_bench.scene import Scene


def rounded(value: Any, digits: int = 3) -> float:
    """``value`` as a float of ``digits`` decimals (the reports' figures)."""
    return round(float(value), digits)


# -- against a generated scene's truth -------------------------------------------------------


@dataclass(slots=True)
class Tally:
    """What one detector did on one frame set."""

    times_ms: list[float] = field(default_factory=list)
    found: int = 0
    visible: int = 0
    false_positives: int = 0
    centre_errors: list[float] = field(default_factory=list)
    distance_errors: list[float] = field(default_factory=list)

    def extend(self, other: Tally) -> None:
        """Add what ``other`` counted (another pass over frames)."""
        self.times_ms += other.times_ms
        self.found += other.found
        self.visible += other.visible
        self.false_positives += other.false_positives
        self.centre_errors += other.centre_errors
        self.distance_errors += other.distance_errors

    def add(self, scene: Scene, detections: Sequence[Detection], ms: float | None) -> None:
        if ms is not None:
            self.times_ms.append(ms)
        found, visible, false_pos, centre, distance = score(scene, detections)
        self.found += found
        self.visible += visible
        self.false_positives += false_pos
        self.centre_errors += centre
        self.distance_errors += distance

    @property
    def recall(self) -> float:
        return self.found / self.visible if self.visible else 1.0

    def summary(self) -> dict[str, Any]:
        times = np.asarray(self.times_ms, dtype=np.float64)
        out: dict[str, Any] = {
            "frames": int(times.size),
            "median_ms": rounded(np.median(times)) if times.size else None,
            "p99_ms": rounded(np.percentile(times, 99)) if times.size else None,
            "mean_ms": rounded(times.mean()) if times.size else None,
            "recall": round(self.recall, 4),
            "found": self.found,
            "visible": self.visible,
            "false_positives": self.false_positives,
            "centre_error_px": (
                rounded(np.median(self.centre_errors)) if self.centre_errors else None
            ),
            "distance_error_pct": (
                rounded(100.0 * float(np.median(self.distance_errors)))
                if self.distance_errors
                else None
            ),
        }
        return out


def score(
    scene: Scene, detections: Sequence[Detection]
) -> tuple[int, int, int, list[float], list[float]]:
    """(found, visible, false positives, centre errors, relative distance errors) of a frame.

    A detection is a tag if a tag with its id lies within max(3 px, 30 % of its side) of its
    centre; it counts toward recall when that tag is fully visible and unoccluded (detections
    of partly hidden tags are neither found nor false). Anything else is a false positive.
    """
    camera = scene.camera
    intrinsics = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy)
    targets = [m for m in scene.markers if m.visible and not m.occluded]
    matched: set[int] = set()
    false_pos = 0
    centre: list[float] = []
    distance: list[float] = []
    for det in detections:
        centre_det = np.asarray(det.corners, dtype=np.float64).mean(axis=0)
        hit = None
        for index, marker in enumerate(scene.markers):
            if marker.tag_id != det.tag_id:
                continue
            err = float(np.linalg.norm(centre_det - marker.corner_mean))
            if err <= max(3.0, 0.3 * marker.side_px):
                hit = index
                break
        if hit is None:
            false_pos += 1
            continue
        marker = scene.markers[hit]
        if not (marker.visible and not marker.occluded) or hit in matched:
            continue
        matched.add(hit)
        centre.append(float(np.linalg.norm(centre_det - marker.corner_mean)))
        pose = estimate_pose(det.corners, marker.size_m, intrinsics)
        if pose is not None:
            distance.append(abs(pose.distance_m - marker.distance_m) / marker.distance_m)
    return len(matched), len(targets), false_pos, centre, distance


# -- against a person's labels ---------------------------------------------------------------

#: Upper edges of the size buckets (mean side of a found marker, pixels).
SIZE_EDGES: Final = (24.0, 48.0, 96.0, 192.0)


def size_bucket(side_px: float) -> str:
    """The name of the size bucket of a marker whose mean side is ``side_px``."""
    low = 0.0
    for edge in SIZE_EDGES:
        if side_px < edge:
            return f"{low:.0f}-{edge:.0f} px"
        low = edge
    return f">= {low:.0f} px"


BUCKETS: Final = (*(size_bucket(edge - 1.0) for edge in SIZE_EDGES), size_bucket(SIZE_EDGES[-1]))


class Labels(Protocol):
    """What a person read on a frame (a labelled item of the dataset)."""

    @property
    def markers(self) -> Mapping[int, int]:
        """Id -> how many markers of that id."""

    @property
    def unknown_markers(self) -> int:
        """Markers seen but not read."""

    @property
    def out_of_view(self) -> frozenset[int]:
        """Labelled ids out of the picture, or cut by its border, on this frame."""


@dataclass(slots=True)
class Score:
    """What one detector did on a group of labelled frames."""

    frames: int = 0
    labelled: int = 0  # labelled markers over the frames (id-frames on video)
    found: int = 0
    false_ids: int = 0
    unverified: int = 0
    times_ms: list[float] = field(default_factory=list)
    buckets: Counter[str] = field(default_factory=Counter)
    false_buckets: Counter[str] = field(default_factory=Counter)
    false_examples: Counter[int] = field(default_factory=Counter)
    found_ids: Counter[int] = field(default_factory=Counter)
    labelled_ids: Counter[int] = field(default_factory=Counter)

    def add(self, labels: Labels, detections: Sequence[Detection], ms: float) -> None:
        self.frames += 1
        self.times_ms.append(ms)
        self.labelled += sum(labels.markers.values())
        self.labelled_ids.update(labels.markers)
        left = dict(labels.markers)
        unknown = labels.unknown_markers
        for detection in detections:
            if left.get(detection.tag_id, 0) > 0:
                left[detection.tag_id] -= 1
                self.found += 1
                self.found_ids[detection.tag_id] += 1
                self.buckets[size_bucket(mean_side(detection.corners))] += 1
            elif detection.tag_id in labels.out_of_view:
                self.unverified += 1  # a labelled marker cut by the border
            elif unknown > 0:
                unknown -= 1
                self.unverified += 1
            else:
                self.false_ids += 1
                self.false_examples[detection.tag_id] += 1
                self.false_buckets[size_bucket(mean_side(detection.corners))] += 1

    def extend(self, other: Score) -> None:
        """Add what ``other`` counted (another item of the group)."""
        self.frames += other.frames
        self.labelled += other.labelled
        self.found += other.found
        self.false_ids += other.false_ids
        self.unverified += other.unverified
        self.times_ms += other.times_ms
        self.buckets.update(other.buckets)
        self.false_buckets.update(other.false_buckets)
        self.false_examples.update(other.false_examples)
        self.found_ids.update(other.found_ids)
        self.labelled_ids.update(other.labelled_ids)

    @property
    def missed(self) -> dict[int, int]:
        """Labelled id -> how many of its markers (id-frames on video) were not reported."""
        return {
            tag: count - self.found_ids[tag]
            for tag, count in sorted(self.labelled_ids.items())
            if count > self.found_ids[tag]
        }

    def summary(self) -> dict[str, Any]:
        times = np.asarray(self.times_ms, dtype=np.float64)
        return {
            "frames": self.frames,
            "labelled": self.labelled,
            "found": self.found,
            "false_ids": self.false_ids,
            "unverified": self.unverified,
            "share_found": round(self.found / self.labelled, 4) if self.labelled else None,
            "median_ms": rounded(np.median(times)) if times.size else None,
            "mean_ms": rounded(times.mean()) if times.size else None,
            "buckets": {b: self.buckets.get(b, 0) for b in BUCKETS},
            "false_buckets": {b: self.false_buckets.get(b, 0) for b in BUCKETS},
            "false_examples": {str(k): v for k, v in sorted(self.false_examples.items())},
            "found_ids": {str(k): v for k, v in sorted(self.found_ids.items())},
            "missed": {str(k): v for k, v in self.missed.items()},
        }
