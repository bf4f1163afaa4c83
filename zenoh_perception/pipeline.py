"""Frame -> grey -> detections -> per-tag geometry -> selection. Pure: no Zenoh, no logging."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from zenoh_perception.detect.colour import ChromaCheck, ColourLimits
from zenoh_perception.detection import (
    ConvertingDetector,
    Detection,
    Detector,
    aruco_dictionary,
    make_detector,
)
from zenoh_perception.frames import Frame, to_gray
from zenoh_perception.geometry import (
    closeness_from_area,
    closeness_from_distance,
    mean_side,
    polygon_area,
    tag_center,
)
from zenoh_perception.pose import Intrinsics, estimate_pose
from zenoh_perception.selection import Policy, TagMessage, TagObservation, selected_message
from zenoh_perception.settings import Settings


@dataclass(frozen=True, slots=True)
class Analysis:
    """What the pipeline found in one frame."""

    tags: tuple[TagObservation, ...]
    selected: TagMessage
    convert_ms: float
    detect_ms: float


def observe(
    detection: Detection,
    width: int,
    height: int,
    settings: Settings,
    intrinsics: Intrinsics | None = None,
) -> TagObservation:
    """Geometry of one detection: centre, area, closeness and (when possible) pose."""
    x, y = tag_center(detection.corners)
    area = polygon_area(detection.corners)
    closeness = closeness_from_area(area, width, height)
    corners = tuple((cx, cy) for cx, cy in np.asarray(detection.corners, np.float64).tolist())
    size = settings.tag_size_for(detection.tag_id)
    pose = estimate_pose(detection.corners, size, intrinsics) if intrinsics is not None else None
    if pose is None:
        return TagObservation(detection.tag_id, x, y, closeness, corners, area)
    if settings.metric == "distance":
        closeness = closeness_from_distance(pose.distance_m, settings.max_range_m)
    return TagObservation(
        detection.tag_id, x, y, closeness, corners, area, pose.distance_m, pose.rvec, pose.tvec
    )


def intrinsics_from_settings(settings: Settings) -> Intrinsics | None:
    if not settings.has_intrinsics:
        return None
    return Intrinsics(
        settings.camera_fx, settings.camera_fy, settings.camera_cx, settings.camera_cy
    )


class TagFinder:
    """What runs on every frame, in the service and in the bench: the detector, fed the colour
    frame when it converts only what it reads, and then it also runs the colour check
    (within ``colour``) on its candidates; else the detector on the frame converted to
    grey, then the colour check on the detections of colour frames. Last, tags whose mean side
    is shorter than ``min_side_px`` (0: off) are dropped."""

    def __init__(
        self,
        detector: Detector,
        dictionary: str,
        colour: ColourLimits,
        min_side_px: float = 0.0,
    ) -> None:
        self.detector = detector
        self._min_side_px = min_side_px
        # decided once: a runtime Protocol check inspects the object on every call
        self._converting = detector if isinstance(detector, ConvertingDetector) else None
        self._colour = colour
        # the check after detection: a converting detector runs its own (every colour encoding
        # has a grey conversion, so it is the one that gets colour frames)
        after = colour.active and self._converting is None
        self._chroma = ChromaCheck(aruco_dictionary(dictionary)) if after else None

    def find(self, frame: Frame) -> tuple[list[Detection], float]:
        """The tags in ``frame``, and the seconds spent converting the whole frame to grey
        first (0 when the detector converts what it reads: its time then includes that)."""
        code = frame.encoding.to_gray
        if code is not None and self._converting is not None:
            # it checks the colour of its candidates itself, before refining them
            detections = self._converting.detect_converting(frame.pixels, code, self._colour)
            return self._large_enough(detections), 0.0
        start = time.perf_counter()
        gray = to_gray(frame)
        converted = time.perf_counter()
        detections = self.detector.detect(gray)
        if self._chroma is not None and detections and frame.pixels.ndim == 3:
            # tags are black on white: coloured look-alikes (signs, icons) go here
            detections = self._chroma.keep(frame.pixels, detections, self._colour)
        return self._large_enough(detections), converted - start

    def _large_enough(self, detections: list[Detection]) -> list[Detection]:
        if self._min_side_px <= 0.0 or not detections:
            return detections
        return [d for d in detections if mean_side(d.corners) >= self._min_side_px]


class Pipeline:
    """Turns decoded frames into an :class:`Analysis`.

    ``intrinsics`` starts from the settings and may be replaced at run time (CameraInfo).
    """

    def __init__(self, settings: Settings, detector: Detector | None = None) -> None:
        self.settings = settings
        if settings.opencv_threads > 0:
            cv2.setNumThreads(settings.opencv_threads)
        if detector is None:
            detector = make_detector(
                settings.detector,
                settings.dictionary,
                full_scan_period=settings.full_scan_period,
                scan_threads=settings.scan_threads,
            )
        colour = ColourLimits(settings.max_tag_chroma, settings.max_black_tint)
        self._finder = TagFinder(detector, settings.dictionary, colour, settings.min_tag_side_px)
        self.intrinsics: Intrinsics | None = intrinsics_from_settings(settings)
        self._policy = Policy(settings.policy)

    def process(self, frame: Frame) -> Analysis:
        start = time.perf_counter()
        detections, convert_s = self._finder.find(frame)
        detected = time.perf_counter()
        width, height = frame.width, frame.height
        tags = tuple(observe(d, width, height, self.settings, self.intrinsics) for d in detections)
        selected = selected_message(tags, width, height, self._policy)
        return Analysis(
            tags=tags,
            selected=selected,
            convert_ms=convert_s * 1e3,
            detect_ms=(detected - start - convert_s) * 1e3,
        )
