"""The project's detector: OpenCV ArUco candidates, verified and refined, tracked between frames.

Design (measured reasons: see "Measurements" below and ``zenoh-perception bench``)
--------------------------------------------------------------------------------
1. Full scan. ``cv2.aruco.ArucoDetector`` on the grey frame with ONE adaptive-threshold window
   (3 px) instead of OpenCV's three (3, 13, 23): thresholding and contour finding dominate the
   cost and scale with the number of windows, while the small window alone still finds the
   small, far tags (larger windows only add large tags, which the small window also finds).
   Bits are read with 8 px per cell instead of 4 and one bit error is corrected (the default
   corrects none for DICT_4X4_50): together they read markers from about 11 px wide, where the
   default misses most; the false ids this could add are removed by step 2.
2. Verification and refinement of every candidate (:mod:`zenoh_perception.detect.refine`):
   corners are re-measured from the four outer border edges (sub-pixel, about 0.02 px median
   centre error), then the ideal marker, quiet zone included, is fitted photometrically. Codes
   without a white quiet zone, bright blobs and pictograms in dark boxes (which decode as valid
   DICT_4X4_50 ids with the default detector) fit badly and are rejected.
3. Tracking. A confirmed marker becomes a track. On the next frames it is looked for where its
   constant-velocity prediction puts it: first by refining the predicted corners directly and
   fitting the model (no detection at all), then, if that fails, by running the detector in a
   small region around the prediction (downscaled for large markers). Full scans then only run
   every ``full_scan_period`` frames to discover new markers, or at once when the frame does not
   look like the previous one (scene cut: a 40x24 thumbnail differs by more than
   ``scene_cut_level`` grey levels on average), or when a track is lost.

Guarantees: a marker that a full scan finds is reported at most ``full_scan_period`` frames
after it appears, and on the very frame it appears when the frame is a scene cut (so unrelated
frames are each fully scanned). Only markers confirmed on the current frame are reported: a
marker that disappears is not reported on the next frame (tracks that miss are searched for up
to ``max_missed`` frames, silently, then dropped). One instance per stream.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.refine import (
    MarkerModel,
    Refined,
    acceptance_threshold,
    fit_marker,
    refine_corners,
)
from zenoh_perception.detection import Detection, aruco_dictionary
from zenoh_perception.errors import SettingsError

Gray = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float64]

_THUMB_SIZE: Final = (40, 24)
_ROI_TARGET_SIDE: Final = 48.0  # markers larger than this are searched in a downscaled region
_MIN_SIDE_PX: Final = 8.0  # smallest marker side a full scan looks for
_MIN_IMAGE_PX: Final = 12  # images narrower than this cannot hold a marker and quiet zone
_REVERIFY_FRAMES: Final = 5  # a followed marker is fitted again at least this often...
_REVERIFY_SCALE: Final = 0.15  # ...and when its size changed by more than this fraction
_FOLLOW_TOLERANCE_PX: Final = 0.4  # a followed marker's corners: one pass unless they moved more
_SCAN_TOLERANCE_PX: Final = 0.25  # scan candidates start from OpenCV's sub-pixel corners
_SHARP_BLUR_PX: Final = 1.5  # a frame whose markers' edges are this sharp needs no coarse scan


@dataclass(frozen=True, slots=True)
class FastDetectorConfig:
    """Knobs of :class:`FastDetector` (defaults are the measured best; see the module doc)."""

    track: bool = True
    full_scan_period: int = 4
    scene_cut_level: float = 12.0
    max_missed: int = 2
    verify: bool = True
    refine: bool = True
    scan_windows: tuple[int, int, int] = (5, 5, 10)  # adaptive threshold min, max, step
    coarse_windows: tuple[int, int, int] = (9, 9, 10)  # same, half-resolution scan
    roi_windows: tuple[int, int, int] = (3, 13, 5)
    pixels_per_cell: int = 8
    error_correction_rate: float = 1.0
    scan_threads: int = 1

    def __post_init__(self) -> None:
        if self.full_scan_period < 1:
            msg = f"full_scan_period must be >= 1, got {self.full_scan_period}"
            raise SettingsError(msg)
        if self.scan_threads not in (1, 2):
            msg = f"scan_threads must be 1 or 2, got {self.scan_threads}"
            raise SettingsError(msg)
        if self.max_missed < 0:
            msg = f"max_missed must be >= 0, got {self.max_missed}"
            raise SettingsError(msg)
        for name in ("scan_windows", "coarse_windows", "roi_windows"):
            low, high, step = getattr(self, name)
            if not (3 <= low <= high and step >= 1):
                msg = f"{name} must be (min >= 3, max >= min, step >= 1), got {low, high, step}"
                raise SettingsError(msg)


@dataclass(slots=True)
class _Track:
    tag_id: int
    corners: Quad
    seen: int  # frame number of the last confirmation
    verified: int  # frame number of the last model fit that passed
    verified_side: float  # marker side (pixels) then
    velocity: Quad = field(default_factory=lambda: np.zeros((4, 2)))
    tried: int = -1  # frame number of the last search
    blur_px: float = math.inf  # edge blur at the last refinement

    def predicted(self, frame: int) -> Quad:
        out: Quad = self.corners + self.velocity * (frame - self.seen)
        return out

    def update(self, quad: Quad, frame: int) -> None:
        self.velocity = (quad - self.corners) / max(frame - self.seen, 1)
        self.corners = quad
        self.seen = frame


@dataclass(slots=True)
class DetectorStats:
    """What the detector did since it was created (the bench prints these)."""

    frames: int = 0
    full_scans: int = 0
    scene_cuts: int = 0
    followed_direct: int = 0
    followed_roi: int = 0
    lost: int = 0
    rejected: int = 0
    coarse_skipped: int = 0


def _parameters(
    windows: tuple[int, int, int], config: FastDetectorConfig, min_perimeter_rate: float
) -> Any:
    params = cv2.aruco.DetectorParameters()
    params.adaptiveThreshWinSizeMin = windows[0]
    params.adaptiveThreshWinSizeMax = windows[1]
    params.adaptiveThreshWinSizeStep = windows[2]
    params.perspectiveRemovePixelPerCell = config.pixels_per_cell
    params.errorCorrectionRate = config.error_correction_rate
    params.minMarkerPerimeterRate = min_perimeter_rate
    # OpenCV's sub-pixel corners are a better start than its polygon corners (median error
    # 0.3 px instead of 1 px): fewer iterations of our own edge refinement, at no scan cost
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return params


def _side(quad: Quad) -> float:
    """Mean side length (plain floats: numpy calls on 4 points cost more than the maths)."""
    p = quad.tolist()
    return sum(math.dist(p[i], p[(i + 1) % 4]) for i in range(4)) / 4.0


def _centre(quad: Quad) -> tuple[float, float]:
    p = quad.tolist()
    return (sum(x for x, _ in p) / 4.0, sum(y for _, y in p) / 4.0)


class FastDetector:
    """Tuned, verifying, tracking ArUco detector (see the module doc). Not thread-safe."""

    def __init__(
        self, dictionary: str = "DICT_4X4_50", config: FastDetectorConfig | None = None
    ) -> None:
        self.config = config if config is not None else FastDetectorConfig()
        self._dictionary = aruco_dictionary(dictionary)
        self._model = MarkerModel(self._dictionary)
        self._cells = self._model.cells
        self._scanners: dict[tuple[int, int, int, int], Any] = {}  # (h, w, coarse, thread)
        self._roi_detector = cv2.aruco.ArucoDetector(
            self._dictionary, _parameters(self.config.roi_windows, self.config, 0.03)
        )
        self._tracks: list[_Track] = []
        self._frame = 0
        self._thumb: npt.NDArray[np.float32] | None = None
        self._since_full = 0
        self._pool: ThreadPoolExecutor | None = None
        self.stats = DetectorStats()

    def close(self) -> None:
        """Stop the scan worker thread, if any (the detector stays usable)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def reset(self) -> None:
        """Forget every track (the next frame is fully scanned)."""
        self._tracks = []
        self._thumb = None

    # -- per frame ----------------------------------------------------------------------------

    def detect(self, gray: Gray) -> list[Detection]:
        """Markers confirmed in ``gray`` (a single-channel uint8 image)."""
        if gray.ndim != 2 or gray.dtype != np.uint8:
            msg = f"expected a 2-D uint8 grey image, got {gray.dtype} {gray.shape}"
            raise ValueError(msg)
        cfg = self.config
        self.stats.frames += 1
        if min(gray.shape) < _MIN_IMAGE_PX:  # no room for a marker and its quiet zone
            self.reset()
            return []
        frame = self._frame = self._frame + 1
        cut = self._scene_cut(gray) if cfg.track else True
        if cut:
            self._tracks = []
        self._since_full += 1
        for track in self._tracks:  # (none after a cut)
            self._follow(gray, track, frame)
        lost = any(track.seen != frame for track in self._tracks)
        if cut or lost or self._since_full >= cfg.full_scan_period:
            self._full_scan(gray, frame)
        self._tracks = [t for t in self._tracks if frame - t.seen <= cfg.max_missed]
        return [
            Detection(t.tag_id, t.corners.astype(np.float32))
            for t in self._tracks
            if t.seen == frame
        ]

    def _scene_cut(self, gray: Gray) -> bool:
        # every 8th pixel, then area-averaged: 0.04 ms at HD720 (a direct INTER_AREA: 0.4 ms)
        thumb = np.asarray(
            cv2.resize(gray[::8, ::8], _THUMB_SIZE, interpolation=cv2.INTER_AREA),
            dtype=np.float32,
        )
        previous, self._thumb = self._thumb, thumb
        if previous is None:
            return True
        level = float(cv2.norm(thumb, previous, cv2.NORM_L1)) / thumb.size
        if level > self.config.scene_cut_level:
            self.stats.scene_cuts += 1
            return True
        return False

    def _full_scan(self, gray: Gray, frame: int) -> None:
        """Scan the frame at full resolution; then at half resolution with a larger threshold
        window unless this frame is known to be sharp (a marker confirmed on it has edges
        blurred by at most :data:`_SHARP_BLUR_PX`): only blur hides markers from the first
        scan, and blur (camera motion, focus) is shared by the whole frame. Candidates that
        are tracked markers already followed on this frame are not confirmed again."""
        self._since_full = 0
        self.stats.full_scans += 1
        coarse = None
        if self.config.scan_threads == 2 and min(gray.shape) >= 4 * _MIN_IMAGE_PX:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(1, thread_name_prefix="fast-detector")
            coarse = self._pool.submit(self._coarse, gray)  # meanwhile, on the other core
        self._take(gray, frame, self._detect_in(gray, coarse=False))
        sharp = any(t.seen == frame and t.blur_px <= _SHARP_BLUR_PX for t in self._tracks)
        if sharp:
            self.stats.coarse_skipped += 1
            return
        self._take(gray, frame, coarse.result() if coarse is not None else self._coarse(gray))

    def _take(self, gray: Gray, frame: int, candidates: list[tuple[int, Quad]]) -> None:
        for tag_id, quad in candidates:
            track = self._nearest(tag_id, quad, frame)
            if track is not None and track.seen == frame:
                continue  # already confirmed this frame (followed, or by the other scan)
            confirmed = self._confirm(gray, tag_id, quad)
            if confirmed is None:
                continue
            corners, blur = confirmed
            if track is None:
                track = _Track(tag_id, corners, frame, frame, _side(corners))
                self._tracks.append(track)
            else:
                track.update(corners, frame)
                track.verified, track.verified_side = frame, _side(corners)
            track.blur_px = blur

    def _nearest(self, tag_id: int, quad: Quad, frame: int) -> _Track | None:
        centre = _centre(quad)
        best: _Track | None = None
        best_d = max(_side(quad), 20.0)
        for track in self._tracks:
            if track.tag_id != tag_id:
                continue
            dist = math.dist(_centre(track.predicted(frame)), centre)
            if dist < best_d:
                best, best_d = track, dist
        return best

    # -- stages -------------------------------------------------------------------------------

    def _scanner(self, shape: tuple[int, int], coarse: bool, worker: int = 0) -> Any:
        key = (shape[0], shape[1], int(coarse), worker)
        scanner = self._scanners.get(key)
        if scanner is None:
            windows = self.config.coarse_windows if coarse else self.config.scan_windows
            # sides from 8 px (16 px at full resolution for the half-resolution scan)
            params = _parameters(windows, self.config, 4.0 * _MIN_SIDE_PX / max(shape))
            scanner = cv2.aruco.ArucoDetector(self._dictionary, params)
            self._scanners[key] = scanner
        return scanner

    def _detect_in(self, image: Gray, coarse: bool, worker: int = 0) -> list[tuple[int, Quad]]:
        shape = (int(image.shape[0]), int(image.shape[1]))
        corners, ids, _ = self._scanner(shape, coarse, worker).detectMarkers(image)
        return _pairs(corners, ids)

    def _coarse(self, gray: Gray) -> list[tuple[int, Quad]]:
        if min(gray.shape) < 4 * _MIN_IMAGE_PX:
            return []  # the fine scan covers small images
        half: Gray = np.asarray(
            cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA), dtype=np.uint8
        )
        return [(i, (q + 0.5) * 2.0 - 0.5) for i, q in self._detect_in(half, coarse=True)]

    def _confirm(self, gray: Gray, tag_id: int, quad: Quad) -> tuple[Quad, float] | None:
        """Refined corners and edge blur (px; inf if unmeasured) if the candidate is a real
        marker, else None."""
        refined = None
        if self.config.refine:
            refined = refine_corners(gray, quad, self._cells, tolerance_px=_SCAN_TOLERANCE_PX)
        corners = refined.corners if refined is not None else quad
        if self.config.verify and not self._passes(gray, tag_id, corners, refined):
            return None
        return corners, refined.blur_px if refined is not None else math.inf

    def _passes(self, gray: Gray, tag_id: int, corners: Quad, refined: Refined | None) -> bool:
        """The model fit at ``corners`` says: a real marker ``tag_id``."""
        reliable = refined is not None and refined.blur_reliable
        blur = (refined.blur_x_px, refined.blur_y_px) if refined and reliable else None
        fit = fit_marker(gray, corners, tag_id, self._model, blur)
        if fit.score <= acceptance_threshold(fit.cell_px, fit.noise):
            return True
        self.stats.rejected += 1
        return False

    def _follow(self, gray: Gray, track: _Track, frame: int) -> None:
        """Find a tracked marker near its prediction: refine the predicted corners directly;
        the model fit is redone every :data:`_REVERIFY_FRAMES` frames or when the marker's
        size changed by more than :data:`_REVERIFY_SCALE` (the border found where the marker
        was predicted, at the size it had, is the marker in between); then the detector in a
        region around the prediction."""
        track.tried = frame
        predicted = track.predicted(frame)
        if self.config.refine:
            refined = refine_corners(
                gray, predicted, self._cells, max_iterations=2, tolerance_px=_FOLLOW_TOLERANCE_PX
            )
            if refined is not None:
                side = _side(refined.corners)
                fresh = frame - track.verified < _REVERIFY_FRAMES
                same_size = abs(side / track.verified_side - 1.0) < _REVERIFY_SCALE
                track.blur_px = refined.blur_px
                if (fresh and same_size) or not self.config.verify:
                    self.stats.followed_direct += 1
                    track.update(refined.corners, frame)
                    return
                if self._passes(gray, track.tag_id, refined.corners, refined):
                    self.stats.followed_direct += 1
                    track.update(refined.corners, frame)
                    track.verified, track.verified_side = frame, side
                    return
        found = self._search_roi(gray, track, predicted)
        if found is not None:
            corners, track.blur_px = found
            self.stats.followed_roi += 1
            track.update(corners, frame)
            track.verified, track.verified_side = frame, _side(corners)
            return
        self.stats.lost += 1

    def _search_roi(self, gray: Gray, track: _Track, predicted: Quad) -> tuple[Quad, float] | None:
        side = _side(predicted)
        motion = float(np.abs(track.velocity).max()) * 0.5
        margin = max(0.6 * side, 8.0) + motion
        height, width = gray.shape
        x0 = max(int(predicted[:, 0].min() - margin), 0)
        y0 = max(int(predicted[:, 1].min() - margin), 0)
        x1 = min(int(predicted[:, 0].max() + margin) + 1, width)
        y1 = min(int(predicted[:, 1].max() + margin) + 1, height)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return None
        roi = gray[y0:y1, x0:x1]
        scale = 1.0
        if side > 2.0 * _ROI_TARGET_SIDE:
            scale = side / _ROI_TARGET_SIDE
            size = (max(int((x1 - x0) / scale), 8), max(int((y1 - y0) / scale), 8))
            roi = np.asarray(cv2.resize(roi, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)
            scale = (x1 - x0) / size[0]
        corners, ids, _ = self._roi_detector.detectMarkers(roi)
        centre = _centre(predicted)
        best: Quad | None = None
        best_d = math.inf
        for tag_id, quad in _pairs(corners, ids):
            if tag_id != track.tag_id:
                continue
            full = (quad + 0.5) * scale - 0.5 + np.array([x0, y0], dtype=np.float64)
            dist = math.dist(_centre(full), centre)
            if dist < best_d:
                best, best_d = full, dist
        if best is None:
            return None
        return self._confirm(gray, track.tag_id, best)


def _unique(candidates: list[tuple[int, Quad]]) -> list[tuple[int, Quad]]:
    """Candidates without the duplicates of overlapping scans (same id, same place)."""
    kept: list[tuple[int, Quad]] = []
    places: list[tuple[int, tuple[float, float]]] = []
    for tag_id, quad in candidates:
        centre = _centre(quad)
        limit = 0.3 * _side(quad)
        if not any(i == tag_id and math.dist(c, centre) < limit for i, c in places):
            kept.append((tag_id, quad))
            places.append((tag_id, centre))
    return kept


def _pairs(corners: Any, ids: Any) -> list[tuple[int, Quad]]:
    if ids is None or len(ids) == 0:
        return []
    flat = np.asarray(ids).reshape(-1)
    return [
        (int(tag_id), np.asarray(quad, dtype=np.float64).reshape(4, 2))
        for tag_id, quad in zip(flat, corners, strict=True)
    ]
