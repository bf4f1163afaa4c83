"""Choosing the one tag a frame reports on ``tag``.

Policies:

- ``closest`` (default): lowest closeness metric; ties go to the tag nearer the image centre,
  then to the lower id.
- ``center``: nearest the image centre; ties go to the lower closeness metric, then the lower
  id.

Closeness values from different metrics are not comparable: with ``metric = "distance"`` a tag
without a pose (no size known for its id, or no intrinsics yet) keeps its ``area`` closeness,
and ``closest`` ranks every such tag after every tag whose closeness is a distance. Under
``center`` the same order only breaks ties of the centre distance.

With no detection the selection is :data:`NO_TAG` (id -1, all zeros).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

from zenoh_perception.tags.geometry import distance_to_center


class Policy(StrEnum):
    CLOSEST = "closest"
    CENTER = "center"


class Metric(StrEnum):
    """What a closeness value was computed from (see :mod:`zenoh_perception.tags.geometry`)."""

    AREA = "area"
    DISTANCE = "distance"


@dataclass(frozen=True, slots=True)
class TagMessage:
    """The four fields of the ROS 2 StarterProjectTag message, in wire order."""

    tag_id: int
    x_tag_center_pixel: float
    y_tag_center_pixel: float
    closeness_metric: float


#: The selection when nothing is detected.
NO_TAG: Final = TagMessage(-1, 0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class TagObservation:
    """One detected tag with its derived geometry."""

    tag_id: int
    x: float
    y: float
    closeness: float
    corners: tuple[tuple[float, float], ...]
    area_px: float
    distance_m: float | None = None
    rvec: tuple[float, float, float] | None = field(default=None)
    tvec: tuple[float, float, float] | None = field(default=None)
    metric: Metric = Metric.AREA  # what ``closeness`` was computed from
    dictionary: str = ""  # the dictionary the id was decoded in ("" when not known)
    #: the pose may be flipped (:mod:`zenoh_perception.tags.pose`): not ranked by, no /tf
    ambiguous: bool = False
    #: RMS reprojection errors (pixels) of the pose and of IPPE's other solution
    pose_errors: tuple[float, float] | None = None

    def message(self) -> TagMessage:
        return TagMessage(self.tag_id, self.x, self.y, self.closeness)


def selection_key(
    width: int, height: int, policy: Policy = Policy.CLOSEST
) -> Callable[[TagObservation], tuple[float, ...]]:
    """The key ``policy`` ranks tags by (the least first), in a frame of ``width`` x
    ``height``: sorting by it puts the tag :func:`select_tag` picks first."""

    def centre_offset(tag: TagObservation) -> float:
        return distance_to_center(tag.x, tag.y, width, height)

    def metric_rank(tag: TagObservation) -> int:
        # A distance (a pose) ranks before an area: the two scales are not comparable.
        return 0 if tag.metric == Metric.DISTANCE else 1

    if policy is Policy.CENTER:
        return lambda t: (centre_offset(t), metric_rank(t), t.closeness, t.tag_id, t.y, t.x)
    # Last keys (y, x) only make the choice independent of detection order in exact ties.
    return lambda t: (metric_rank(t), t.closeness, centre_offset(t), t.tag_id, t.y, t.x)


def select_tag(
    tags: Sequence[TagObservation], width: int, height: int, policy: Policy = Policy.CLOSEST
) -> TagObservation | None:
    """The tag ``policy`` picks among ``tags``, or None when there is none."""
    if not tags:
        return None
    return min(tags, key=selection_key(width, height, policy))


def selected_message(
    tags: Sequence[TagObservation], width: int, height: int, policy: Policy = Policy.CLOSEST
) -> TagMessage:
    """The message to publish: the selected tag's fields, or :data:`NO_TAG`."""
    chosen = select_tag(tags, width, height, policy)
    return NO_TAG if chosen is None else chosen.message()
