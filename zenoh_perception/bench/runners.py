"""The two detectors the benches compare, run the same way on the same BGRA frames.

:class:`Baseline` is what users would otherwise run: BGRA -> BGR (``cv2.cvtColor``) then
``cv2.aruco.ArucoDetector(dictionary, DetectorParameters()).detectMarkers`` on the BGR image;
its time includes the conversion. :class:`Project` is a service detector on the BGRA frame as
the service runs it (:class:`~zenoh_perception.pipeline.TagFinder`: grey conversion included),
timed the same way, one instance per stream. Both run one frame after the other in one
process, the order rotating from frame to frame (:func:`rotation`), so a slower moment of the
machine affects both alike.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, Final, Protocol, TypeVar

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.bench.framesets import BoardFrame
from zenoh_perception.bench.progress import Progress, tick
from zenoh_perception.bench.scoring import Tally
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.grids import GridKeeper
from zenoh_perception.detect.opencv import aruco_dictionary, detections_from_opencv
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.pipeline import TagFinder
from zenoh_perception.scene import Scene
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import ENCODINGS, Frame

Image = npt.NDArray[np.uint8]
T = TypeVar("T")

#: The dictionary of the generated frame sets.
DICTIONARY: Final = "DICT_4X4_50"
BGRA8: Final = ENCODINGS["bgra8"]
#: The labelled-dataset bench's names for OpenCV's default and the service's detector.
PAIR: Final = ("opencv", "service")


class Runner(Protocol):
    """A detector as the bench runs it: detections and milliseconds for one BGRA image."""

    def run(self, image: Image) -> tuple[list[Detection], float]: ...


class Baseline:
    """BGRA -> BGR, then OpenCV's default ArUco detector."""

    name = "baseline"

    def __init__(self, dictionary: str = DICTIONARY) -> None:
        params = cv2.aruco.DetectorParameters()
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def run(self, image: Image) -> tuple[list[Detection], float]:
        start = time.perf_counter()
        converted = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        corners, ids, _ = self._detector.detectMarkers(converted)
        elapsed = (time.perf_counter() - start) * 1e3
        return detections_from_opencv(corners, ids), elapsed


class Project:
    """A service detector (default: ``tracking``; one per frame set, like one per stream) run
    on the BGRA frame as the service's pipeline runs it (:class:`TagFinder`: grey conversion
    included, tags shorter than ``min_side_px`` dropped, look-alikes vetoed when ``verify``,
    tags held back until seen on ``confirm_frames`` frames)."""

    def __init__(
        self,
        dictionary: str = DICTIONARY,
        detector: Detector | None = None,
        min_side_px: float = 0.0,
        *,
        verify: bool = True,
        confirm_frames: int = 1,
    ) -> None:
        self.detector = make_detector("tracking", dictionary) if detector is None else detector
        verifier = Verifier(dictionary) if verify else None
        self._finder = TagFinder(self.detector, min_side_px, verifier, confirm_frames)

    def run(self, image: Image) -> tuple[list[Detection], float]:
        start = time.perf_counter()
        detections, _ = self._finder.find(Frame(image, BGRA8, None, "bench", None))
        elapsed = (time.perf_counter() - start) * 1e3
        return detections, elapsed


def pair(dictionary: str, settings: Settings) -> dict[str, Runner]:
    """:data:`PAIR`: OpenCV's default the way a user runs it, and the service's detector with
    ``settings`` as the service runs it."""
    detector = make_detector(
        settings.detector,
        dictionary,
        full_scan_period=settings.full_scan_period,
        second_look=settings.second_look,
    )
    return {
        "opencv": Baseline(dictionary),
        "service": Project(
            dictionary,
            detector,
            settings.min_tag_side_px,
            verify=settings.verify,
            confirm_frames=settings.confirm_frames,
        ),
    }


def rotation(order: Sequence[T], index: int) -> list[T]:
    """``order`` rotated for frame ``index``: each one goes first in turn."""
    shift = index % len(order)
    return [*order[shift:], *order[:shift]]


def compare(
    scenes: Sequence[Scene], runners: Sequence[Runner], progress: Progress | None, label: str
) -> list[Tally]:
    """Run every runner on every frame (order rotating per frame); one tally per runner."""
    tallies = [Tally() for _ in runners]
    for index, scene in enumerate(scenes):
        for k in rotation(range(len(runners)), index):
            detections, ms = runners[k].run(scene.image)
            tallies[k].add(scene, detections, ms)
        tick(progress, label)
    return tallies


def board_case(
    frames: Sequence[BoardFrame],
    after: Image,
    progress: Progress | None,
    settings: Settings | None = None,
) -> dict[str, Any]:
    """OpenCV's default and the service's detector (``settings``, default: the service's
    defaults) on the board frames, one after the other as a storm, then on ``after``, a
    good frame: per frame the milliseconds and tags found of each; the good frame's time."""
    runners = pair(DICTIONARY, settings if settings is not None else Settings())
    rows = []
    for index, frame in enumerate(frames):
        row: dict[str, Any] = {"kind": frame.kind, "square_px": frame.square}
        for name in rotation(PAIR, index):
            detections, ms = runners[name].run(frame.image)
            ids = {d.tag_id for d in detections}
            row[name] = {
                "ms": ms,
                "found": len(ids & frame.ids),
                "false": len(ids - frame.ids),
                "tags": len(frame.ids),
            }
        rows.append(row)
        tick(progress, "boards")
    good = {}
    for name in PAIR:
        _, ms = runners[name].run(after)
        good[name] = ms
    summary: dict[str, Any] = {
        name: {
            "median_ms": float(np.median([row[name]["ms"] for row in rows])),
            "max_ms": float(max(row[name]["ms"] for row in rows)),
            "found": sum(row[name]["found"] for row in rows),
            "false": sum(row[name]["false"] for row in rows),
            "tags": sum(row[name]["tags"] for row in rows),
        }
        for name in PAIR
    }
    return {
        "frames": rows,
        "summary": summary,
        "after_storm_ms": good,
        "plain_frame_cost_ms": keeper_cost_ms(after),
        "plain_frame_opencv_ms": good["opencv"],
    }


def keeper_cost_ms(image: Image, repeat: int = 2000) -> float:
    """What the grid keeper adds to the read of a plain frame (``image``, BGRA), in ms: its
    preparation, the clock and its verdict on the markers, averaged over ``repeat`` runs."""
    gray = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)
    keeper = GridKeeper()
    corners = np.zeros((4, 2), np.float32)
    start = time.perf_counter()
    for _ in range(repeat):
        begin = time.perf_counter()
        keeper.prepare(gray)
        keeper.record(time.perf_counter() - begin, gray.size)
        keeper.keep(corners)
    return (time.perf_counter() - start) * 1e3 / repeat
