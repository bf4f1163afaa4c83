"""Frame -> grey -> detections -> per-tag geometry -> selection. Pure: no Zenoh, no logging."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from typing import Final

import cv2
import numpy as np

from zenoh_perception.detect.confirm import Confirmer
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.detect.verify import REASONS, Verifier
from zenoh_perception.settings import Settings
from zenoh_perception.tags.geometry import (
    closeness_from_area,
    closeness_from_distance,
    mean_side,
    polygon_area,
    tag_center,
)
from zenoh_perception.tags.pose import Intrinsics, estimate_pose
from zenoh_perception.tags.selection import (
    Metric,
    Policy,
    TagMessage,
    TagObservation,
    selected_message,
)
from zenoh_perception.wire.frames import Frame, to_gray

#: Why a detection OpenCV reported is dropped: the verifier's reasons, and a marker not yet
#: seen on ``confirm_frames`` frames in a row.
VETO_REASONS: Final = (*REASONS, "unconfirmed")


@dataclass(frozen=True, slots=True)
class Analysis:
    """What the pipeline found in one frame."""

    tags: tuple[TagObservation, ...]
    selected: TagMessage
    convert_ms: float
    detect_ms: float
    #: The frame is not of the size of the CameraInfo whose intrinsics are in use: they were
    #: left out for it.
    intrinsics_mismatch: bool = False


def observe(
    detection: Detection,
    width: int,
    height: int,
    settings: Settings,
    intrinsics: Intrinsics | None = None,
) -> TagObservation:
    """Geometry of one detection: centre, area, closeness and (when possible) pose.

    With ``metric = "distance"`` the closeness is the pose's distance when there is a pose,
    else the area closeness; the observation's ``metric`` says which.
    """
    x, y = tag_center(detection.corners)
    area = polygon_area(detection.corners)
    closeness = closeness_from_area(area, width, height)
    corners = tuple((cx, cy) for cx, cy in np.asarray(detection.corners, np.float64).tolist())
    size = settings.tag_size_for(detection.tag_id)
    pose = estimate_pose(detection.corners, size, intrinsics) if intrinsics is not None else None
    if pose is None:
        return TagObservation(
            detection.tag_id, x, y, closeness, corners, area, dictionary=detection.dictionary
        )
    metric = Metric.AREA
    if settings.metric == Metric.DISTANCE:
        closeness = closeness_from_distance(pose.distance_m, settings.max_range_m)
        metric = Metric.DISTANCE
    return TagObservation(
        detection.tag_id,
        x,
        y,
        closeness,
        corners,
        area,
        pose.distance_m,
        pose.rvec,
        pose.tvec,
        metric,
        detection.dictionary,
    )


def intrinsics_from_settings(settings: Settings) -> Intrinsics | None:
    if not settings.has_intrinsics:
        return None
    return Intrinsics(
        settings.camera_fx, settings.camera_fy, settings.camera_cx, settings.camera_cy
    )


class TagFinder:
    """What runs on every frame, in the service and in the bench: the frame converted to grey,
    the detector, then (``min_side_px`` > 0) tags whose mean side is shorter dropped, then
    (with a ``verifier``) the detections it vetoes dropped, then (``confirm_frames`` > 1) those
    not yet seen on that many frames in a row held back; counted by reason in ``vetoed``."""

    def __init__(
        self,
        detector: Detector,
        min_side_px: float = 0.0,
        verifier: Verifier | None = None,
        confirm_frames: int = 1,
    ) -> None:
        self.detector = detector
        self._min_side_px = min_side_px
        self._verifier = verifier
        self._confirmer = Confirmer(confirm_frames) if confirm_frames > 1 else None
        # every reason present from the start: a status read from another thread copies a
        # dict whose keys never change
        self.vetoed: Counter[str] = Counter(dict.fromkeys(VETO_REASONS, 0))

    def find(self, frame: Frame) -> tuple[list[Detection], float]:
        """The tags in ``frame``, and the seconds spent converting it to grey first."""
        start = time.perf_counter()
        # a detector in another process offers the buffer it reads from (None: any array), so
        # that the grey image is not copied into it
        buffer = getattr(self.detector, "gray_buffer", None)
        gray = to_gray(frame, None if buffer is None else buffer(*frame.pixels.shape[:2]))
        converted = time.perf_counter()
        detections = self.detector.detect(gray)
        if self._min_side_px > 0.0 and detections:
            detections = [d for d in detections if mean_side(d.corners) >= self._min_side_px]
        if self._verifier is not None and detections:
            detections, reasons = self._verifier.verify(gray, detections)
            self.vetoed.update(reasons)
        if self._confirmer is not None:
            detections, held = self._confirmer.confirm(gray.shape, detections)
            self.vetoed["unconfirmed"] += held
        return detections, converted - start


def detector_for(settings: Settings) -> Detector:
    """The detector the settings name: what :class:`Pipeline` runs unless given another (the
    service's deadline runs it in a child process, built there by this function). Sets the
    process's OpenCV threads as ``opencv_threads`` says."""
    if settings.opencv_threads > 0:
        cv2.setNumThreads(settings.opencv_threads)
    return make_detector(
        settings.detector, settings.dictionary, full_scan_period=settings.full_scan_period
    )


class Pipeline:
    """Turns decoded frames into an :class:`Analysis`.

    ``intrinsics`` starts from the settings and may be replaced at run time (CameraInfo,
    :meth:`use_camera_info`): a CameraInfo's intrinsics are applied only to frames of its
    image size.
    """

    def __init__(self, settings: Settings, detector: Detector | None = None) -> None:
        self.settings = settings
        if settings.opencv_threads > 0:
            cv2.setNumThreads(settings.opencv_threads)
        if detector is None:
            detector = detector_for(settings)
        verifier = Verifier(settings.dictionary) if settings.verify else None
        self._finder = TagFinder(
            detector, settings.min_tag_side_px, verifier, settings.confirm_frames
        )
        # one attribute, replaced whole: a frame never sees intrinsics with another's size
        self._camera: tuple[Intrinsics | None, tuple[int, int] | None] = (
            intrinsics_from_settings(settings),
            None,
        )
        self._policy = Policy(settings.policy)

    @property
    def intrinsics(self) -> Intrinsics | None:
        return self._camera[0]

    @intrinsics.setter
    def intrinsics(self, intrinsics: Intrinsics | None) -> None:
        """Intrinsics for frames of any size (as from the settings)."""
        self._camera = (intrinsics, None)

    def use_camera_info(self, intrinsics: Intrinsics, width: int, height: int) -> None:
        """Intrinsics for frames of ``width`` x ``height`` only (a CameraInfo's)."""
        self._camera = (intrinsics, (width, height))

    @property
    def vetoed(self) -> Counter[str]:
        """Detections vetoed so far, by reason (:data:`VETO_REASONS`)."""
        return self._finder.vetoed

    def process(self, frame: Frame) -> Analysis:
        start = time.perf_counter()
        detections, convert_s = self._finder.find(frame)
        detected = time.perf_counter()
        width, height = frame.width, frame.height
        intrinsics, size = self._camera
        mismatch = intrinsics is not None and size is not None and size != (width, height)
        if mismatch:
            intrinsics = None
        tags = tuple(observe(d, width, height, self.settings, intrinsics) for d in detections)
        selected = selected_message(tags, width, height, self._policy)
        return Analysis(
            tags=tags,
            selected=selected,
            convert_ms=convert_s * 1e3,
            detect_ms=(detected - start - convert_s) * 1e3,
            intrinsics_mismatch=mismatch,
        )
