"""The detectors the benches compare, run the same way on the same BGRA frames.

:class:`Baseline` is what users would otherwise run: BGRA -> BGR (``cv2.cvtColor``) then
``cv2.aruco.ArucoDetector(dictionary, DetectorParameters()).detectMarkers`` on the BGR image;
its time includes the conversion. :class:`Best` is the same with OpenCV's most thorough
setting measured (:data:`BEST_SETTING`): what a user who tunes OpenCV would run, shown beside
the default, never judged. :class:`Project` is a service detector on the BGRA frame as the
service runs it (:class:`~zenoh_perception.pipeline.TagFinder`: grey conversion included),
timed the same way, one instance per stream. All run one frame after the other in one
process, the order rotating from frame to frame (:func:`rotation`), so a slower moment of the
machine affects each alike.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any, Final, Protocol, TypeVar

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.grids import GridKeeper
from zenoh_perception.detect.opencv import aruco_dictionary, detections_from_opencv
from zenoh_perception.detect.types import Detection, Detector
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.pipeline import TagFinder
from zenoh_perception.settings import Settings
from zenoh_perception.settings.sections import DetectorSettings
from zenoh_perception.wire.frames import ENCODINGS, Frame
from zenoh_perception_bench.framesets import BoardFrame
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.scene import Scene
from zenoh_perception_bench.scoring import Tally

Image = npt.NDArray[np.uint8]
T = TypeVar("T")

#: The dictionary of the generated frame sets.
DICTIONARY: Final = "DICT_4X4_50"
BGRA8: Final = ENCODINGS["bgra8"]
#: The labelled-dataset bench's names for OpenCV's default and the service's detector: the
#: two its goals judge.
PAIR: Final = ("opencv", "service")
#: The name of OpenCV's best setting (:class:`Best`) in the benches' reports.
BEST: Final = "best"
#: Every detector the labelled-dataset bench runs, in the order its cells show them
#: (``opencv/best/service``): OpenCV's best setting is shown, not judged.
SHOWN: Final = ("opencv", BEST, "service")
#: OpenCV's best setting: the most thorough ``DetectorParameters`` measured on the real corpus
#: (docs/benchmarks.md, "Seeing more than OpenCV's default"), both replacements there at once:
#: adaptive threshold windows 3..53 in steps of 4 (13 windows, the default reads 3 windows
#: 3..23 in steps of 10) for markers under uneven light, and a minimum marker perimeter of 2 %
#: of the image's larger side (default 3 %) for smaller markers. It is what a user tuning
#: OpenCV for recall would pick; the two together cost about 3.5-4.5x the default's time a
#: frame on the corpus (each alone about 2x).
BEST_SETTING: Final[Mapping[str, float]] = {
    "adaptiveThreshWinSizeMin": 3,
    "adaptiveThreshWinSizeMax": 53,
    "adaptiveThreshWinSizeStep": 4,
    "minMarkerPerimeterRate": 0.02,
}


class Runner(Protocol):
    """A detector as the bench runs it: detections and milliseconds for one BGRA image."""

    def run(self, image: Image) -> tuple[list[Detection], float]: ...


def detector_parameters(changes: Mapping[str, float]) -> cv2.aruco.DetectorParameters:
    """OpenCV's default ``DetectorParameters`` with ``changes`` (attribute -> value) made."""
    params = cv2.aruco.DetectorParameters()
    for key, value in changes.items():
        if not hasattr(params, key):  # a misspelt name would otherwise add a plain attribute
            msg = f"DetectorParameters has no {key}"
            raise AttributeError(msg)
        setattr(params, key, type(getattr(params, key))(value))
    return params


class Baseline:
    """BGRA -> BGR, then OpenCV's ArUco detector: its default parameters, or these with
    ``changes`` made."""

    name = "baseline"

    def __init__(
        self, dictionary: str = DICTIONARY, changes: Mapping[str, float] | None = None
    ) -> None:
        params = detector_parameters(changes or {})
        self.parameters = params
        self._detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)

    def run(self, image: Image) -> tuple[list[Detection], float]:
        start = time.perf_counter()
        converted = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        corners, ids, _ = self._detector.detectMarkers(converted)
        elapsed = (time.perf_counter() - start) * 1e3
        return detections_from_opencv(corners, ids), elapsed


class Best(Baseline):
    """:class:`Baseline` with OpenCV's best setting (:data:`BEST_SETTING`): same conversion,
    same timing."""

    name = BEST

    def __init__(self, dictionary: str = DICTIONARY) -> None:
        super().__init__(dictionary, BEST_SETTING)


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


def pair(dictionary: str, settings: DetectorSettings, *, best: bool = False) -> dict[str, Runner]:
    """:data:`PAIR`: OpenCV's default the way a user runs it, and the service's detector with
    ``settings`` as the service runs it; with ``best``, :data:`SHOWN`: OpenCV's best setting
    between them."""
    detector = make_detector(
        settings.detector,
        dictionary,
        full_scan_period=settings.full_scan_period,
        second_look=settings.second_look,
    )
    return {
        "opencv": Baseline(dictionary),
        **({BEST: Best(dictionary)} if best else {}),
        "service": Project(
            dictionary,
            detector,
            settings.min_tag_side_px,
            verify=settings.verify,
            confirm_frames=settings.confirm_frames,
        ),
    }


def rotation(order: Sequence[T], index: int) -> list[T]:
    """``order`` for frame ``index``: a row of a balanced Latin square (Williams' design).

    Over ``n`` frames (``2n`` when ``n`` is odd) each one goes first equally often and comes
    right after each other one equally often. A cyclic shift would not do: each would always
    follow the same one, and a program that leaves the cores busy after its answer (OpenCV's
    spinning pool) would always slow the same next one.
    """
    n = len(order)
    if n < 2:
        return list(order)
    first = [0]
    low, high = 1, n - 1
    while len(first) < n:
        first.append(low)
        low += 1
        if len(first) < n:
            first.append(high)
            high -= 1
    row = index % (n if n % 2 == 0 else 2 * n)
    picked = [order[(k + row) % n] for k in first]
    return picked if row < n else picked[::-1]


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
    runners = pair(DICTIONARY, (settings if settings is not None else Settings()).detection)
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
