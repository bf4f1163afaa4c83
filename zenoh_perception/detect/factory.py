"""A detector by name, as the settings give it."""

from __future__ import annotations

from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.tracking import TrackingConfig, TrackingDetector
from zenoh_perception.detect.types import DETECTORS, Detector
from zenoh_perception.errors import SettingsError


def make_detector(name: str, dictionary: str, *, full_scan_period: int = 4) -> Detector:
    """The detector called ``name`` (one of :data:`~.types.DETECTORS`) for ``dictionary``.

    Raises:
        SettingsError: unknown detector or dictionary, or a period out of bounds.

    """
    if name == "opencv":
        return OpenCvDetector(dictionary)
    if name == "tracking":
        return TrackingDetector(dictionary, TrackingConfig(full_scan_period=full_scan_period))
    msg = f"unknown detector {name!r}; choose one of {', '.join(DETECTORS)}"
    raise SettingsError(msg)
