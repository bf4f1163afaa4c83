"""A detector by name, as the settings give it."""

from __future__ import annotations

from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.second_look import SecondLook
from zenoh_perception.detect.tracking import TrackingConfig, TrackingDetector
from zenoh_perception.detect.types import DETECTORS, Detector, DetectorKind, dictionary_names
from zenoh_perception.errors import SettingsError


def make_detector(
    name: str,
    dictionary: str,
    *,
    full_scan_period: int = 4,
    wary: bool = False,
    second_look: bool = True,
) -> Detector:
    """The detector called ``name`` (one of :data:`~.types.DETECTORS`) for ``dictionary``;
    ``wary``: one that replaces a detector whose read stalled, keeping periodic grids away
    from its first read on (see :mod:`~zenoh_perception.detect.grids`); ``second_look``: frames
    are looked at again for markers the first read misses (see
    :mod:`~zenoh_perception.detect.second_look`).

    Raises:
        SettingsError: unknown detector or dictionary, or a period out of bounds.

    """
    if name not in DETECTORS:
        msg = f"unknown detector {name!r}; choose one of {', '.join(DETECTORS)}"
        raise SettingsError(msg)
    look = SecondLook(dictionary_names(dictionary)) if second_look else None
    if name == DetectorKind.OPENCV:
        return OpenCvDetector(dictionary, wary=wary, second_look=look)
    config = TrackingConfig(full_scan_period=full_scan_period)
    return TrackingDetector(dictionary, config, wary=wary, second_look=look)
