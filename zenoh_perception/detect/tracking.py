"""OpenCV's ArUco detector, run on the whole frame only when it must be.

Every marker this detector reports was decided by ``cv2.aruco.ArucoDetector`` with OpenCV's
default parameters, on the whole frame (a *scan*) or on a region of it (*following*). What it
adds is the choice of where to look. Each frame is first compared with the previous one on a
thumbnail (one pixel per 16 x 16 block, the mean of 16 of its pixels), and:

- the whole frame is scanned on the first frame; on a scene cut (the thumbnail differs by more
  than ``scene_cut_level`` grey levels on average, so independent frames are each scanned,
  and the markers of the scene before are forgotten);
  when no known marker was in view on the previous frame; when a block away from the known
  markers changed by more than ``appear_level`` (something appeared there); when a followed
  marker is not found again where it was expected (it moved farther than its region, was
  hidden or left); when OpenCV reads, on the frame at a quarter of its size (a glimpse, a
  sixteenth of the pixels, for markers of GLIMPSE_MIN_SIDE_PX or more), a marker that no
  known one explains (a large marker turning into view); and at least every
  ``full_scan_period`` frames, so a marker that enters a followed scene unnoticed is reported
  within that many frames;
- otherwise the frame is followed: each known marker is read in a region around the place its
  last two sightings predict (constant velocity), with a margin of half its side plus its
  motion, at the scale that keeps its side at least READ_SIDE_PX (a large marker needs no
  more pixels to be read; its corners are then refined at full resolution). A region inside
  one already read as finely is skipped and a marker read twice is reported once. A region
  is read for markers of at least a third of the followed one's perimeter
  (REGION_MIN_SHARE): any such marker OpenCV decides on there is reported, known or new;
- a marker that neither its region nor the scan that followed found is still read in its
  region for ``coast_frames`` frames: a small or blurred marker that OpenCV reads on some
  frames and not on others is read again as soon as it can be, not at the next scan;
- with no marker known, a frame whose thumbnail differs from the previous one by less than
  ``still_level`` on average (a still scene) is not read again until the period is over.

One instance per stream; not thread-safe.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.regions import Rect, around, inside, perimeter, same_marker, side
from zenoh_perception.detect.types import Detection, Detector, Looker
from zenoh_perception.errors import SettingsError

Gray = npt.NDArray[np.uint8]
Change = npt.NDArray[np.int16]

#: Side of the blocks of the thumbnail that tells scene cuts, appearances and still scenes.
BLOCK: Final = 16
#: The thumbnail's block means are taken over every SAMPLE-th pixel of every SAMPLE-th row.
SAMPLE: Final = 4
#: Scale of the glimpse: the frame read at 1/GLIMPSE of its size between scans.
GLIMPSE: Final = 4
#: Smallest marker the glimpse looks for, side in full-resolution pixels: smaller ones have too
#: few pixels left at 1/GLIMPSE to be read, and skipping their specks makes the glimpse cheap.
GLIMPSE_MIN_SIDE_PX: Final = 32.0
#: A followed marker's region is read for markers at least this share of its perimeter: a
#: marker does not shrink to a third between two frames, and OpenCV spends most of its time
#: on the small contours this skips. A smaller marker new in the region is left to the scans.
REGION_MIN_SHARE: Final = 1 / 3
#: Side a followed marker keeps when its region is read at a reduced scale, pixels.
READ_SIDE_PX: Final = 64.0
#: Smallest margin of a followed marker's region, pixels (OpenCV needs a quiet zone to read).
MIN_MARGIN_PX: Final = 20.0


@dataclass(frozen=True, slots=True)
class TrackingConfig:
    """How often whole frames are scanned, and what counts as a scene cut, an appearance or a
    still scene."""

    full_scan_period: int = 4
    coast_frames: int = 8
    scene_cut_level: float = 12.0
    appear_level: float = 48.0
    still_level: float = 0.5
    glimpse: bool = True

    def __post_init__(self) -> None:
        if not 1 <= self.full_scan_period <= 1000:
            msg = f"full_scan_period must be 1..1000, not {self.full_scan_period}"
            raise SettingsError(msg)
        if not 0 <= self.coast_frames <= 1000:
            msg = f"coast_frames must be 0..1000, not {self.coast_frames}"
            raise SettingsError(msg)
        for name in ("scene_cut_level", "appear_level", "still_level"):
            value = getattr(self, name)
            if not 0.0 <= value <= 255.0:
                msg = f"{name} must be 0..255, not {value}"
                raise SettingsError(msg)


@dataclass(slots=True)
class _Track:
    tag_id: int
    corners: npt.NDArray[np.float32]
    motion: npt.NDArray[np.float32] = field(default_factory=lambda: np.zeros(2, dtype=np.float32))
    missed: int = 0  # frames since it was last found (its corners are where it was then)

    def predicted(self) -> npt.NDArray[np.float32]:
        """Where constant motion puts its corners on the frame being read."""
        return self.corners + self.motion * (self.missed + 1)

    def coasting(self) -> _Track:
        """The track of a frame on which it was not found."""
        return _Track(self.tag_id, self.corners, self.motion, self.missed + 1)

    def scale(self) -> int:
        """How much smaller its region can be read: its side still READ_SIDE_PX or more."""
        return max(1, int(side(self.corners) // READ_SIDE_PX))

    def region(self, width: int, height: int) -> Rect:
        """Around both where it was last seen and where constant motion puts it now (a
        coasting marker may have stopped), inside the frame."""
        points = np.concatenate((self.corners, self.predicted()))
        margin = max(MIN_MARGIN_PX, 0.5 * side(self.corners)) + float(np.abs(self.motion).max())
        return around(points, margin, width, height)


def _centre(corners: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    out: npt.NDArray[np.float32] = corners.mean(axis=0)
    return out


class TrackingDetector(Detector):
    """OpenCV's ArUco detector on whole frames when needed, on regions around known markers
    in between (see the module documentation)."""

    def __init__(
        self,
        dictionary: str = "DICT_4X4_50",
        config: TrackingConfig | None = None,
        *,
        wary: bool = False,
        second_look: Looker | None = None,
    ) -> None:
        self.config = config if config is not None else TrackingConfig()
        # its whole-frame scans get the second look (frames in between are regions)
        self._opencv = OpenCvDetector(dictionary, wary=wary, second_look=second_look)
        self._tracks: list[_Track] = []
        self._thumb: Change | None = None
        self._since_scan = 0
        self._scanned = False  # the frame read last was scanned whole
        self.counters: dict[str, int] = dict.fromkeys(
            (
                "frames",
                "scans",
                "scene_cuts",
                "appearances",
                "glimpses",
                "lost_rescans",
                "followed",
                "regions",
                "still_skips",
            ),
            0,
        )

    def detect(self, gray: Gray) -> list[Detection]:
        self._scanned = False
        self.counters["frames"] += 1
        self._since_scan += 1
        height, width = gray.shape[:2]
        change = self._change(gray)
        if change is None:
            return self._scan(gray)
        if float(change.mean()) > self.config.scene_cut_level:
            self.counters["scene_cuts"] += 1
            self._tracks = []  # another scene: where its markers were says nothing now
            return self._scan(gray)
        if self._since_scan >= self.config.full_scan_period:
            return self._scan(gray)
        if not any(t.missed == 0 for t in self._tracks):
            if not self._tracks and float(change.mean()) < self.config.still_level:
                self.counters["still_skips"] += 1
                return []
            return self._scan(gray)
        if self._appeared(change, width, height):
            self.counters["appearances"] += 1
            return self._scan(gray)
        glimpsed = self.config.glimpse and self._glimpsed(gray)
        found = None if glimpsed else self._follow(gray)
        if glimpsed:
            self.counters["glimpses"] += 1
            return self._scan(gray)
        if found is None:
            self.counters["lost_rescans"] += 1
            return self._scan(gray)
        self.counters["followed"] += 1
        return found

    def reset(self) -> None:
        """Forget the stream: the next frame is scanned."""
        self._tracks = []
        self._thumb = None
        self._since_scan = 0

    def _change(self, gray: Gray) -> Change | None:
        """Absolute change of each block's mean grey level since the previous frame (None:
        no previous frame of this size).

        The means are taken over every 4th pixel of every 4th row (16 of a block's 256): a
        sixth of the cost of averaging every pixel, within a grey level of it, and far below
        the levels the decisions use. Every frame pays for it, a scanned one too.
        """
        height, width = gray.shape[:2]
        sampled = np.ascontiguousarray(gray[SAMPLE // 2 :: SAMPLE, SAMPLE // 2 :: SAMPLE])
        size = (max(1, width // BLOCK), max(1, height // BLOCK))
        thumb = cv2.resize(sampled, size, interpolation=cv2.INTER_AREA).astype(np.int16)
        previous, self._thumb = self._thumb, thumb
        if previous is None or previous.shape != thumb.shape:
            self._tracks = []
            return None
        change: Change = np.abs(thumb - previous)
        return change

    def _appeared(self, change: Change, width: int, height: int) -> bool:
        """Whether a block away from every known marker changed by more than appear_level."""
        changed = change > self.config.appear_level
        if not changed.any():
            return False
        for track in self._tracks:
            x0, y0, x1, y1 = track.region(width, height)
            changed[y0 // BLOCK : -(-y1 // BLOCK), x0 // BLOCK : -(-x1 // BLOCK)] = False
        return bool(changed.any())

    def _glimpsed(self, gray: Gray) -> bool:
        """Whether OpenCV's detector reads, on the frame at a quarter of its size, a marker
        that no known one explains (a large marker turning into view or coming into focus)."""
        height, width = gray.shape[:2]
        # halved twice: OpenCV's area resize is several times faster for a factor of 2
        small: Gray = gray
        for factor in (2, GLIMPSE):
            size = (max(1, width // factor), max(1, height // factor))
            small = np.asarray(cv2.resize(small, size, interpolation=cv2.INTER_AREA), np.uint8)
        smallest = 4.0 * GLIMPSE_MIN_SIDE_PX / GLIMPSE
        for found in self._opencv.detect(small, min_perimeter_px=smallest, frame=False):
            centre = _centre(found.corners) * GLIMPSE + (GLIMPSE - 1) / 2
            if not any(
                track.tag_id == found.tag_id
                and float(np.linalg.norm(_centre(track.predicted()) - centre))
                <= max(side(track.corners), 2.0 * MIN_MARGIN_PX)
                for track in self._tracks
            ):
                return True
        return False

    def look_again(self) -> list[Detection]:
        """What the second look adds to the frame read last when it was scanned whole and its
        look left until after its tag (see :meth:`OpenCvDetector.look_again`)."""
        return self._opencv.look_again() if self._scanned else []

    def _scan(self, gray: Gray) -> list[Detection]:
        self._scanned = True
        self.counters["scans"] += 1
        self._since_scan = 0
        found = self._opencv.detect(gray)
        unmatched = list(found)
        coasting: list[_Track] = []
        for track in self._tracks:
            match = _nearest(track, unmatched)
            if match is not None:
                unmatched = [d for d in unmatched if d is not match]
            elif track.missed < self.config.coast_frames:
                coasting.append(track.coasting())
        self._tracks = [_Track(d.tag_id, d.corners) for d in found] + coasting
        return found

    def _follow(self, gray: Gray) -> list[Detection] | None:
        """Markers in the regions around the known ones; None when one that the previous
        frame showed is missing."""
        height, width = gray.shape[:2]
        frame_side = max(width, height)
        wanted = [
            (t.region(width, height), t.scale(), REGION_MIN_SHARE * perimeter(t.corners))
            for t in self._tracks
        ]
        found: list[Detection] = []
        read: list[tuple[Rect, int, float]] = []
        for rect, scale, smallest in wanted:
            if any(inside(rect, r) and s <= scale and p <= smallest for r, s, p in read):
                continue  # read already, as finely and for markers as small
            read.append((rect, scale, smallest))
            x0, y0, x1, y1 = rect
            region = gray[y0:y1, x0:x1]
            found_here = self._opencv.detect_region(region, (x0, y0), scale, frame_side, smallest)
            for detection in found_here:
                if not any(same_marker(detection, other) for other in found):
                    found.append(detection)
        self.counters["regions"] += len(read)
        tracks: list[_Track] = []
        unmatched = list(found)
        for track in self._tracks:
            match = _nearest(track, unmatched)
            if match is not None:
                unmatched = [d for d in unmatched if d is not match]
                moved = _centre(match.corners) - _centre(track.corners)
                motion = moved / np.float32(track.missed + 1)
                tracks.append(_Track(match.tag_id, match.corners, motion))
            elif track.missed == 0:
                return None
            elif track.missed < self.config.coast_frames:
                tracks.append(track.coasting())
        tracks += [_Track(d.tag_id, d.corners) for d in unmatched]
        self._tracks = tracks
        return found


def _nearest(track: _Track, candidates: list[Detection]) -> Detection | None:
    """The candidate with the track's id nearest its predicted centre, if within reach."""
    same_id = [c for c in candidates if c.tag_id == track.tag_id]
    if not same_id:
        return None
    expected = _centre(track.predicted())
    reach = (
        max(side(track.corners), 2.0 * MIN_MARGIN_PX)
        + float(np.abs(track.motion).max()) * track.missed
    )
    best: Detection | None = None
    best_distance = reach
    for candidate in same_id:
        distance = float(np.linalg.norm(_centre(candidate.corners) - expected))
        if distance <= best_distance:
            best, best_distance = candidate, distance
    return best


def tracking_counters(detector: Any) -> dict[str, int]:
    """The counters of a :class:`TrackingDetector` (empty for any other detector)."""
    return dict(detector.counters) if isinstance(detector, TrackingDetector) else {}
