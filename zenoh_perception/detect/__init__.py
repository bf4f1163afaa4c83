"""Building blocks of the project's detector (see :mod:`zenoh_perception.fast_detector`).

- :mod:`.refine`: sub-pixel corner refinement from the marker's outer border edges, and the
  photometric model fit that tells real markers from look-alikes.
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
