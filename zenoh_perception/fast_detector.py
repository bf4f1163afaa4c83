"""The project's detector: OpenCV ArUco candidates, verified and refined, tracked between frames.

Design, and why (figures from ``zenoh-perception bench --levers``, HD720, same frames, one
run; the baseline is BGRA->BGR + ``cv2.aruco.ArucoDetector`` with default parameters)
-------------------------------------------------------------------------------------------
1. Full scan at full resolution: ``cv2.aruco.ArucoDetector`` on the grey frame (converted
   straight from BGRA by the pipeline) with ONE adaptive-threshold window of 5 px instead of
   OpenCV's three (3, 13, 23 px). Thresholding and contour finding dominate the cost and scale
   with the number of windows: one 5 px window takes about 0.3x the baseline's time and finds
   as many tags (3 px alone loses blurred tags, 7 px small ones, 3+13 px costs 0.5x for
   nothing more). Cells are read with 8 px per cell instead of 4 and one bit error is
   corrected (OpenCV corrects none for DICT_4X4_50): +15 % recall on the video, whose far tags
   are 11-20 px wide. ArUco3 mode is not used: it loses a third of the tags (all the small
   ones) for no gain. OpenCV's sub-pixel corners are kept as a start for step 2.
2. Every candidate is refined and checked (:mod:`zenoh_perception.detect.refine`), all of a
   frame's candidates in one batch: corners from lines fitted to the four outer border edges
   (median centre error about 0.02 px, ten times below OpenCV's), then the ideal marker, white
   quiet zone included, blurred like its own border edges, is fitted to the image; the code
   cells' residual beyond the image noise must be small. This rejects codes without a quiet
   zone, bright blobs and pictograms in dark boxes (look-alikes OpenCV decodes as valid ids):
   about 98 % of the baseline's false positives go; the rest are look-alikes whose cells are
   2-5 px, where blur makes a pictogram's round strokes look like square cells (the threshold
   is what keeps recall at least the baseline's on small real tags).
3. A half-resolution scan with a 9 px window (a quarter of the pixels) finds tags too blurred
   for the 5 px window (strong motion blur: with it, recall under heavy blur stays near the
   baseline's instead of collapsing). It only runs when the frame is not known to be sharp
   (no marker confirmed on it with edges blurred by at most 1.5 px): blur is shared by the
   whole frame, so on sharp frames it could only find what step 1 found.
4. Tracking. A confirmed marker becomes a track. On the next frames its corners are refined
   where its constant-velocity prediction puts them (all tracks in one batch), and the model
   fit is redone every 5 frames or when its size changed by 15 %; a track that cannot be
   refined there is searched for with the detector in a region around the prediction. Full
   scans then only run every ``full_scan_period`` (8) frames, or at once when a track is lost,
   when the frame does not look like the previous one (scene cut: a 40x24 thumbnail differs by
   more than ``scene_cut_level`` grey levels on average), or when one thumbnail cell away from
   the tracks changed by more than ``appear_level`` (a tag appeared on a still scene). On
   the video this is what makes the detector about 6x faster than the baseline per frame,
   with more recall (tracks hold small tags the scan reads only now and then).

5. Grey on demand (:meth:`FastDetector.detect_converting`, what the pipeline calls on colour
   frames): a followed frame reads only the regions around its tracks and a thumbnail, so
   only those are converted from BGRA; the whole frame only when a full scan runs. Same
   result as converting first, without a third of a followed frame's cost.

6. The colour check (:mod:`zenoh_perception.detect.colour`: tags are black on white, so a
   look-alike with a coloured contrast or a tinted black is not a tag) runs on the scan's
   and the region searches' candidates before they are refined and fitted, when
   :meth:`FastDetector.detect_converting` has the colour frame and colour limits: on
   independent HD720 frames about one candidate in seven is a coloured look-alike, and it
   then costs no refinement; a followed marker, checked when its track started, is not
   checked again on every frame (the pipeline checked every detection of every frame
   before: 0.13 ms a frame on the video).

Guarantees: a marker that a full scan finds is reported at most ``full_scan_period`` frames
after it appears, and on the very frame it appears when that frame is a scene cut or the tag
changes a thumbnail cell by ``appear_level`` (a tag about 1/40 of the frame wide or more), so
unrelated frames are each fully scanned (independent frames: every frame is a cut). Only
markers confirmed on the current frame are reported: a marker that disappears is not reported
on the next frame (a lost track is searched for, silently, for up to ``max_missed`` frames).
One instance per stream; not thread-safe.

Measured and dropped: sharing the scan with a second thread (overlapping halves; OpenCV
releases the GIL) pays only on an otherwise idle second core, and on this shared 2-core box it
lost more than it won (``scan_threads=2`` keeps it available); ``cv2.setNumThreads(1)`` makes
no measurable difference to the project's detector (its scan has one window).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.colour import ChromaCheck, ColourLimits
from zenoh_perception.detect.refine import (
    FitRequest,
    MarkerModel,
    Refined,
    acceptance_threshold,
    bits_match,
    fit_many,
    refine_many,
)
from zenoh_perception.detection import Detection, aruco_dictionary
from zenoh_perception.errors import SettingsError
from zenoh_perception.geometry import mean_side, tag_center

Gray = npt.NDArray[np.uint8]
Image = npt.NDArray[np.uint8]  # (H, W, C) colour
Quad = npt.NDArray[np.float64]

_THUMB_SIZE: Final = (40, 24)
_ROI_TARGET_SIDE: Final = 48.0  # markers larger than this are searched in a downscaled region
_MIN_SIDE_PX: Final = 8.0  # smallest marker side a full scan looks for
_MIN_IMAGE_PX: Final = 12  # images narrower than this cannot hold a marker and quiet zone
_REVERIFY_FRAMES: Final = 5  # a followed marker is fitted again at least this often...
_REVERIFY_SCALE: Final = 0.15  # ...and when its size changed by more than this fraction
_FOLLOW_TOLERANCE_PX: Final = 0.4  # a followed marker's corners: one pass unless they moved more
# A scan's candidates: passes stop once no corner moved this far (a pass removes most of the
# error left). At 0.1 px most candidates took a third pass (2.9 passes a frame instead of 2.3
# on independent HD720 frames, 0.1 ms more) for the same corners within 0.05 px, recall and
# false positives; at 0.4 px, large markers' corners were off by up to 0.06 px.
_SCAN_TOLERANCE_PX: Final = 0.3
_SHARP_BLUR_PX: Final = 1.5  # a frame whose markers' edges are this sharp needs no coarse scan
_OVERLAP_PX: Final = 64  # two-thread scans: rows shared by the upper and lower halves
_PARALLEL_MIN_PIXELS: Final = 500_000


@dataclass(frozen=True, slots=True)
class FastDetectorConfig:
    """Knobs of :class:`FastDetector` (defaults are the measured best; see the module doc)."""

    track: bool = True
    full_scan_period: int = 8
    scene_cut_level: float = 12.0
    appear_level: float = 40.0
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
    colour_rejected: int = 0
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
        self._grey_buffer: Gray | None = None  # detect_converting's grey frame
        self._chroma = ChromaCheck(self._dictionary, self._model)
        # this frame's colour pixels and colour limits, when detect_converting checks them
        self._colour: tuple[Image, ColourLimits] | None = None
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
        return self._detect(_Grey(gray))

    def detect_converting(
        self, pixels: Image, code: int, colour: ColourLimits | None = None
    ) -> list[Detection]:
        """:meth:`detect` of ``cv2.cvtColor(pixels, code)``, with the same result, converting
        only the parts of the frame it reads: on a frame where every tracked marker is
        followed, the regions around the tracks and every 8th pixel for the scene check; the
        whole frame only when a full scan runs. (The grey frame is kept between frames: the
        conversion would otherwise cost a third of a followed frame.)

        ``colour``: the colour check (:mod:`zenoh_perception.detect.colour`) on every
        candidate before it is refined and fitted: coloured look-alikes cost no refinement
        and never become tracks, and a followed marker is not checked again on every frame.
        """
        if pixels.ndim != 3 or pixels.dtype != np.uint8:
            msg = f"expected an (H, W, C) uint8 colour image, got {pixels.dtype} {pixels.shape}"
            raise ValueError(msg)
        height, width = int(pixels.shape[0]), int(pixels.shape[1])
        if self._grey_buffer is None or self._grey_buffer.shape != (height, width):
            self._grey_buffer = np.empty((height, width), dtype=np.uint8)
        usable = colour is not None and colour.active and pixels.shape[2] >= 3
        self._colour = (pixels, colour) if usable and colour is not None else None
        try:
            return self._detect(_Converting(pixels, code, self._grey_buffer))
        finally:
            self._colour = None

    def _detect(self, source: _Source) -> list[Detection]:
        cfg = self.config
        gray = source.gray
        self.stats.frames += 1
        if min(gray.shape) < _MIN_IMAGE_PX:  # no room for a marker and its quiet zone
            self.reset()
            return []
        frame = self._frame = self._frame + 1
        cut, appeared = self._scene_change(source) if cfg.track else (True, False)
        if cut:
            self._tracks = []
        self._since_full += 1
        if self._tracks:  # what following them reads: the search region and its surround
            source.convert([self._reach(track, frame) for track in self._tracks])
        self._follow_all(gray, frame)  # (no tracks after a cut)
        lost = any(track.seen != frame for track in self._tracks)
        if cut or appeared or lost or self._since_full >= cfg.full_scan_period:
            source.convert_all()
            self._full_scan(gray, frame)
        self._tracks = [t for t in self._tracks if frame - t.seen <= cfg.max_missed]
        return [
            Detection(t.tag_id, t.corners.astype(np.float32))
            for t in self._tracks
            if t.seen == frame
        ]

    @staticmethod
    def _reach(track: _Track, frame: int) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) around the prediction of ``track`` holding everything following it
        may read: the search region of :meth:`_search_roi`, then the quiet ring and the edge
        profiles of a marker found at its border."""
        predicted = track.predicted(frame)
        side = mean_side(predicted)
        margin = _search_margin(side, track) + 0.5 * side + 8.0
        x0, y0 = predicted.min(axis=0).tolist()
        x1, y1 = predicted.max(axis=0).tolist()
        return (x0 - margin, y0 - margin, x1 + margin, y1 + margin)

    def _scene_change(self, source: _Source) -> tuple[bool, bool]:
        """(scene cut, something appeared) from a 40x24 thumbnail against the previous one.

        A cut is a mean change above ``scene_cut_level``: tracks are dropped and the frame is
        fully scanned. Something appeared when one thumbnail cell away from every track
        changed by more than ``appear_level`` (a new tag on a static scene, a tag moved in
        front of the camera): the frame is fully scanned, tracks are kept.
        """
        # every 8th pixel, then area-averaged: 0.05 ms at HD720 (a direct INTER_AREA: 0.4 ms)
        thumb = np.asarray(
            cv2.resize(source.every_8th(), _THUMB_SIZE, interpolation=cv2.INTER_AREA),
            dtype=np.float32,
        )
        previous, self._thumb = self._thumb, thumb
        if previous is None:
            return True, False
        diff = np.abs(thumb - previous)
        if float(diff.mean()) > self.config.scene_cut_level:
            self.stats.scene_cuts += 1
            return True, False
        if self._tracks:
            height, width = source.gray.shape
            cell_w, cell_h = width / _THUMB_SIZE[0], height / _THUMB_SIZE[1]
            for track in self._tracks:  # a followed tag's own motion is not news
                x0, y0 = track.corners.min(axis=0)
                x1, y1 = track.corners.max(axis=0)
                c0 = max(int(x0 / cell_w) - 1, 0)
                r0 = max(int(y0 / cell_h) - 1, 0)
                diff[r0 : int(y1 / cell_h) + 2, c0 : int(x1 / cell_w) + 2] = 0.0
        return False, float(diff.max()) > self.config.appear_level

    def _full_scan(self, gray: Gray, frame: int) -> None:
        """Scan the frame at full resolution (:meth:`_fine`); then at half resolution with a
        larger threshold window unless this frame is known to be sharp (a marker confirmed on
        it has edges blurred by at most :data:`_SHARP_BLUR_PX`): only blur hides markers from
        the first scan, and blur (camera motion, focus) is shared by the whole frame.
        Candidates that are tracked markers already followed on this frame are not confirmed
        again."""
        self._since_full = 0
        self.stats.full_scans += 1
        self._take(gray, frame, self._fine(gray))
        if any(t.seen == frame and t.blur_px <= _SHARP_BLUR_PX for t in self._tracks):
            self.stats.coarse_skipped += 1
            return
        self._take(gray, frame, self._coarse(gray))

    def _fine(self, gray: Gray) -> list[tuple[int, Quad]]:
        """Full-resolution candidates. With ``scan_threads == 2`` on frames of half a
        megapixel and more, a second thread scans the lower half while this one scans the
        upper half (OpenCV releases the GIL); the halves overlap by :data:`_OVERLAP_PX` rows,
        so a marker up to about twice as tall lies wholly in one of them, and the second
        thread also scans the frame at quarter resolution for taller ones."""
        height, width = int(gray.shape[0]), int(gray.shape[1])
        if self.config.scan_threads < 2 or height * width < _PARALLEL_MIN_PIXELS:
            return self._detect_in(gray, coarse=False)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="fast-detector")
        top = height // 2 - _OVERLAP_PX
        lower = self._pool.submit(self._lower_and_large, gray, top)
        upper = self._detect_in(gray[: height // 2 + _OVERLAP_PX], coarse=False)
        return _unique(upper + lower.result())

    def _lower_and_large(self, gray: Gray, top: int) -> list[tuple[int, Quad]]:
        shift = np.array([0.0, float(top)])
        found = [(i, q + shift) for i, q in self._detect_in(gray[top:], False, worker=1)]
        quarter: Gray = np.asarray(
            cv2.resize(gray, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA),
            dtype=np.uint8,
        )
        large = self._detect_in(quarter, coarse=True, worker=1)
        return found + [(i, (q + 0.5) * 4.0 - 0.5) for i, q in large]

    def _take(self, gray: Gray, frame: int, candidates: list[tuple[int, Quad]]) -> None:
        """Confirm the candidates (all at once) and update or start their tracks."""
        fresh: list[tuple[int, Quad, _Track | None]] = []
        for tag_id, quad in self._achromatic(candidates):
            track = self._nearest(tag_id, quad, frame)
            if track is None or track.seen != frame:  # else already confirmed on this frame
                fresh.append((tag_id, quad, track))
        confirmed = self._confirm_many(gray, [(tag_id, quad) for tag_id, quad, _ in fresh])
        for (tag_id, _, known), result in zip(fresh, confirmed, strict=True):
            if result is None:
                continue
            corners, blur = result
            track = known if known is not None else self._nearest(tag_id, corners, frame)
            if track is None:
                track = _Track(tag_id, corners, frame, frame, mean_side(corners))
                self._tracks.append(track)
            elif track.seen == frame:
                continue  # a second candidate for a marker confirmed on this frame
            else:
                track.update(corners, frame)
                track.verified, track.verified_side = frame, mean_side(corners)
            track.blur_px = blur

    def _achromatic(self, candidates: list[tuple[int, Quad]]) -> list[tuple[int, Quad]]:
        """The candidates that pass this frame's colour check (all of them without one)."""
        if self._colour is None or not candidates:
            return candidates
        pixels, limits = self._colour
        measures = self._chroma.measure_candidates(pixels, candidates)
        kept = [c for c, m in zip(candidates, measures, strict=True) if m.achromatic(limits)]
        self.stats.colour_rejected += len(candidates) - len(kept)
        return kept

    def _nearest(self, tag_id: int, quad: Quad, frame: int) -> _Track | None:
        centre = tag_center(quad)
        best: _Track | None = None
        best_d = max(mean_side(quad), 20.0)
        for track in self._tracks:
            if track.tag_id != tag_id:
                continue
            dist = math.dist(tag_center(track.predicted(frame)), centre)
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
        return self._confirm_many(gray, [(tag_id, quad)])[0]

    def _confirm_many(
        self, gray: Gray, candidates: list[tuple[int, Quad]]
    ) -> list[tuple[Quad, float] | None]:
        """:meth:`_confirm` for several candidates, refined and fitted in batches."""
        if not candidates:
            return []
        quads = [quad for _, quad in candidates]
        refined: list[Refined | None] = [None] * len(candidates)
        if self.config.refine:
            refined = refine_many(
                gray, quads, self._cells, max_iterations=5, tolerance_px=_SCAN_TOLERANCE_PX
            )
        corners = [r.corners if r is not None else q for r, q in zip(refined, quads, strict=True)]
        passed = [True] * len(candidates)
        if self.config.verify:
            passed = self._passes_many(
                gray, [(c, i) for c, (i, _) in zip(corners, candidates, strict=True)], refined
            )
        return [
            (c, r.blur_px if r is not None else math.inf) if ok else None
            for c, r, ok in zip(corners, refined, passed, strict=True)
        ]

    def _passes_many(
        self, gray: Gray, items: list[tuple[Quad, int]], refined: list[Refined | None]
    ) -> list[bool]:
        requests: list[FitRequest] = []
        for (corners, tag_id), r in zip(items, refined, strict=True):
            blur = (r.blur_x_px, r.blur_y_px) if r is not None and r.blur_reliable else None
            requests.append((corners, tag_id, blur))
        verdicts = []
        for fit in fit_many(gray, requests, self._model):
            ok = fit.score <= acceptance_threshold(fit.cell_px, fit.noise)
            self.stats.rejected += int(not ok)
            verdicts.append(ok)
        return verdicts

    def _follow_all(self, gray: Gray, frame: int) -> None:
        """Find every tracked marker near its prediction, all in one batch: refine the
        predicted corners directly; the model fit is redone every :data:`_REVERIFY_FRAMES`
        frames or when the marker's size changed by more than :data:`_REVERIFY_SCALE` (the
        border found where the marker was predicted, at the size it had, is the marker in
        between), else its cells must still read as its id; a marker not found so is searched
        for with the detector in a region around the prediction (the only way without
        refinement)."""
        if not self._tracks:
            return
        if not self.config.refine:
            for track in self._tracks:
                track.tried = frame
                self._search(gray, track, frame)
            return
        predictions = [track.predicted(frame) for track in self._tracks]
        refined = refine_many(
            gray, predictions, self._cells, max_iterations=2, tolerance_px=_FOLLOW_TOLERANCE_PX
        )
        to_fit: list[tuple[_Track, Refined]] = []
        to_read: list[tuple[_Track, Refined]] = []
        search: list[_Track] = []
        for track, r in zip(self._tracks, refined, strict=True):
            track.tried = frame
            if r is None:
                search.append(track)
                continue
            track.blur_px = r.blur_px
            side = mean_side(r.corners)
            recent = frame - track.verified < _REVERIFY_FRAMES
            if not self.config.verify:
                self.stats.followed_direct += 1
                track.update(r.corners, frame)
            elif recent and abs(side / track.verified_side - 1.0) < _REVERIFY_SCALE:
                to_read.append((track, r))
            else:
                to_fit.append((track, r))
        # between fits, the cells must still read as the track's id (another marker may
        # have taken its place: same border, other code)
        same = bits_match(gray, [(r.corners, t.tag_id) for t, r in to_read], self._model)
        for (track, r), ok in zip(to_read, same, strict=True):
            if ok:
                self.stats.followed_direct += 1
                track.update(r.corners, frame)
            else:
                search.append(track)
        if to_fit:
            verdicts = self._passes_many(
                gray, [(r.corners, t.tag_id) for t, r in to_fit], [r for _, r in to_fit]
            )
            for (track, r), ok in zip(to_fit, verdicts, strict=True):
                if not ok:
                    search.append(track)
                    continue
                self.stats.followed_direct += 1
                track.update(r.corners, frame)
                track.verified, track.verified_side = frame, mean_side(r.corners)
        for track in search:
            self._search(gray, track, frame)

    def _search(self, gray: Gray, track: _Track, frame: int) -> None:
        found = self._search_roi(gray, track, track.predicted(frame))
        if found is not None:
            corners, track.blur_px = found
            self.stats.followed_roi += 1
            track.update(corners, frame)
            track.verified, track.verified_side = frame, mean_side(corners)
            return
        self.stats.lost += 1

    def _search_roi(self, gray: Gray, track: _Track, predicted: Quad) -> tuple[Quad, float] | None:
        side = mean_side(predicted)
        margin = _search_margin(side, track)
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
        centre = tag_center(predicted)
        best: Quad | None = None
        best_d = math.inf
        shift = np.array([x0, y0], dtype=np.float64)
        mine = [
            (i, (q + 0.5) * scale - 0.5 + shift)
            for i, q in _pairs(corners, ids)
            if i == track.tag_id
        ]
        for _, full in self._achromatic(mine):
            dist = math.dist(tag_center(full), centre)
            if dist < best_d:
                best, best_d = full, dist
        if best is None:
            return None
        return self._confirm(gray, track.tag_id, best)


def _search_margin(side: float, track: _Track) -> float:
    """Pixels around a tracked marker's predicted corners searched when it is not where
    predicted: 0.6 of its side (at least 8 px) plus half its last motion per frame."""
    return max(0.6 * side, 8.0) + float(np.abs(track.velocity).max()) * 0.5


def _every_8th(image: Gray | Image) -> Gray:
    """About every 8th pixel of every 8th row (nearest neighbour: no arithmetic on pixels, so
    it commutes with a per-pixel colour conversion). 0.04 ms at HD720 (a strided copy: 0.1)."""
    height, width = int(image.shape[0]), int(image.shape[1])
    size = (-(-width // 8), -(-height // 8))
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_NEAREST), dtype=np.uint8)


class _Source(Protocol):
    """The grey frame a detection reads, and what must be converted before it reads it."""

    @property
    def gray(self) -> Gray: ...
    def every_8th(self) -> Gray: ...
    def convert(self, rects: list[tuple[float, float, float, float]]) -> None: ...
    def convert_all(self) -> None: ...


class _Grey:
    """An already grey frame: nothing to convert."""

    def __init__(self, gray: Gray) -> None:
        self.gray = gray

    def every_8th(self) -> Gray:
        return _every_8th(self.gray)

    def convert(self, rects: list[tuple[float, float, float, float]]) -> None:
        del rects

    def convert_all(self) -> None:
        pass


class _Converting:
    """A colour frame converted to grey on demand into a buffer kept between frames (pixels
    outside the converted parts hold older frames: only what was converted is read)."""

    def __init__(self, pixels: Image, code: int, buffer: Gray) -> None:
        self._pixels = pixels
        self._code = code
        self.gray = buffer
        self._all = False

    def every_8th(self) -> Gray:
        # sampling first, then converting, gives the same pixels as converting first
        return np.asarray(cv2.cvtColor(_every_8th(self._pixels), self._code), dtype=np.uint8)

    def convert(self, rects: list[tuple[float, float, float, float]]) -> None:
        height, width = self.gray.shape
        for x0, y0, x1, y1 in rects:
            c0, r0 = max(int(x0), 0), max(int(y0), 0)
            c1, r1 = min(int(x1) + 2, width), min(int(y1) + 2, height)
            if c1 > c0 and r1 > r0:
                cv2.cvtColor(self._pixels[r0:r1, c0:c1], self._code, dst=self.gray[r0:r1, c0:c1])

    def convert_all(self) -> None:
        if not self._all:
            self._all = True
            cv2.cvtColor(self._pixels, self._code, dst=self.gray)


def _unique(candidates: list[tuple[int, Quad]]) -> list[tuple[int, Quad]]:
    """Candidates without the duplicates of overlapping scans (same id, same place)."""
    kept: list[tuple[int, Quad]] = []
    places: list[tuple[int, tuple[float, float]]] = []
    for tag_id, quad in candidates:
        centre = tag_center(quad)
        limit = 0.3 * mean_side(quad)
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
