"""Building blocks of the project's detector (see :mod:`zenoh_perception.fast_detector`).

- :mod:`.refine`: sub-pixel corner refinement from the marker's outer border edges, and the
  photometric model fit that tells real markers from look-alikes.
- :mod:`.colour`: the colour check that drops coloured look-alikes (tags are black on white).
"""

from __future__ import annotations

from zenoh_perception.detect.refine import (
    FitResult,
    MarkerModel,
    acceptance_threshold,
    fit_marker,
    refine_corners,
)

__all__ = [
    "FitResult",
    "MarkerModel",
    "acceptance_threshold",
    "fit_marker",
    "refine_corners",
]
