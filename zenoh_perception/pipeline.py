"""Frame -> grey -> detections -> per-tag geometry -> selection. Pure: no Zenoh, no logging."""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from zenoh_perception.detect.coarse import CoarseRead, same_answer
from zenoh_perception.detect.confirm import Confirmer
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.rules import REASONS
from zenoh_perception.detect.types import Detection, Detector, dictionary_names
from zenoh_perception.detect.verify import Verifier
from zenoh_perception.settings.sections import DetectorSettings, Selection
from zenoh_perception.tags.corners import MAX_MOVE_CELLS, marker_cells, refine_corners
from zenoh_perception.tags.geometry import (
    closeness_from_area,
    closeness_from_distance,
    distance_to_center,
    mean_side,
    polygon_area,
    tag_center,
)
from zenoh_perception.tags.pose import Intrinsics, PoseMemory, estimate_pose
from zenoh_perception.tags.selection import (
    NO_TAG,
    Metric,
    Policy,
    TagMessage,
    TagObservation,
    selected_message,
    selection_key,
)
from zenoh_perception.wire.frames import Frame, Pixels, to_gray

Gray = Pixels

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
    #: The tag published came from the coarse first read and differs from the whole read's
    #: selection, this (see :func:`~.detect.coarse.same_answer`); else None.
    whole_selected: TagMessage | None = None


def observe(
    detection: Detection,
    width: int,
    height: int,
    selection: Selection,
    intrinsics: Intrinsics | None = None,
    *,
    poses: PoseMemory | None = None,
) -> TagObservation:
    """Geometry of one detection: centre, area, closeness and (when possible) pose, an
    ambiguous one's solution chosen by the stream's ``poses``.

    With ``metric = "distance"`` the closeness is the pose's distance when there is a pose
    that is not ambiguous, else the area closeness; the observation's ``metric`` says which.
    """
    x, y = tag_center(detection.corners)
    area = polygon_area(detection.corners)
    closeness = closeness_from_area(area, width, height)
    corners = tuple(map(tuple, np.asarray(detection.corners, np.float64).tolist()))
    size = selection.tag_size_for(detection.tag_id)
    pose = estimate_pose(detection.corners, size, intrinsics) if intrinsics is not None else None
    if pose is not None and poses is not None:
        pose = poses.choose((detection.dictionary, detection.tag_id), pose)
    if pose is None:
        return TagObservation(
            detection.tag_id, x, y, closeness, corners, area, dictionary=detection.dictionary
        )
    metric = Metric.AREA
    if selection.metric is Metric.DISTANCE and not pose.ambiguous:
        closeness = closeness_from_distance(pose.distance_m, selection.max_range_m)
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
        pose.ambiguous,
        pose.errors,
    )


def refined(gray: Gray, detection: Detection) -> Detection:
    """``detection`` with its corners refined by an edge fit
    (:func:`~zenoh_perception.tags.corners.refine_corners`): its id and dictionary as OpenCV
    decided them."""
    corners, _ = refine_corners(gray, detection.corners, marker_cells(detection.dictionary))
    return replace(detection, corners=corners.astype(np.float32))


#: Floating-point slack of :func:`rank_floor`'s bounds: relative, and absolute (pixels).
_SLACK: Final = 1e-9
_SLACK_PX: Final = 1e-3

#: The first two values of a tag's selection key (:func:`~.tags.selection.selection_key`).
Floor = tuple[float, float]


def rank_floor(
    detection: Detection, width: int, height: int, policy: Policy, *, refine: bool
) -> Floor:
    """A lower bound of the first two values of the selection key of ``detection``'s
    observation under an ``area`` closeness, from OpenCV's corners alone: the refinement
    (``refine``) moves each corner at most :data:`~.tags.corners.MAX_MOVE_CELLS` of a cell,
    which bounds how much larger the tag's area and how much nearer its centre to the
    image's centre it can become."""
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = (
        np.asarray(detection.corners, np.float64).reshape(4, 2).tolist()
    )
    reach = _SLACK_PX
    if refine:
        side = mean_side(detection.corners)
        reach += MAX_MOVE_CELLS * side / marker_cells(detection.dictionary) * (1.0 + _SLACK)
    # an area closeness ranks after a distance's (1, not 0) whatever the policy
    if policy is Policy.CENTER:
        centre = distance_to_center((x0 + x1 + x2 + x3) / 4, (y0 + y1 + y2 + y3) / 4, width, height)
        return centre - reach, 1.0
    # each corner within ``reach``: twice the area moves by at most 2 reach times the
    # diagonals, plus 4 reach^2
    twice = (x0 * y1 - y0 * x1) + (x1 * y2 - y1 * x2) + (x2 * y3 - y2 * x3) + (x3 * y0 - y3 * x0)
    diagonals = math.hypot(x2 - x0, y2 - y0) + math.hypot(x3 - x1, y3 - y1)
    largest = (abs(twice) / 2.0 + reach * diagonals + 2.0 * reach * reach) * (1.0 + _SLACK)
    return 1.0, closeness_from_area(largest, width, height)


def ranked(
    count: int,
    key: Callable[[int], tuple[float, ...]],
    floors: list[Floor] | None,
) -> Iterator[int]:
    """``range(count)`` in the order ``sorted(range(count), key=key)`` gives, asking ``key``
    only for the indices that may come next: those whose ``floors`` (lower bounds of the
    first two values of their key; None: none known) are not above the next one's key."""
    if floors is None:
        yield from sorted(range(count), key=key)
        return
    keys: dict[int, tuple[float, ...]] = {}

    def known(index: int) -> tuple[tuple[float, ...], int]:
        if index not in keys:
            keys[index] = key(index)
        return keys[index], index  # ties go to the lower index, as sorted() leaves them

    left = sorted(range(count), key=floors.__getitem__)
    while left:
        best = known(left[0])
        for index in left[1:]:
            if floors[index] > best[0][:2]:
                break  # this one and every one after it rank later
            best = min(best, known(index))
        left.remove(best[1])
        yield best[1]


def intrinsics_from_settings(selection: Selection) -> Intrinsics | None:
    s = selection
    if not s.has_intrinsics:
        return None
    return Intrinsics(s.camera_fx, s.camera_fy, s.camera_cx, s.camera_cy)


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
        """The tags in ``frame`` (what the service's :class:`Pipeline` reports), and the
        seconds spent converting it to grey first."""
        gray, detections, convert_s = self.detect(frame)
        if self.judges_one_by_one:  # as the service's pipeline: its look after the tag
            detections += self.look_again()
        return self.screen(gray, detections), convert_s

    def detect(
        self, frame: Frame, converted: tuple[Gray, float] | None = None
    ) -> tuple[Gray, list[Detection], float]:
        """The first steps of :meth:`find`: the grey image, the detector's markers at least
        ``min_side_px`` a side, and the seconds the conversion took (``converted``: the grey
        image and those seconds, from :meth:`convert`)."""
        gray, convert_s = self.convert(frame) if converted is None else converted
        detections = self.detector.detect(gray)
        if self._min_side_px > 0.0 and detections:
            detections = [d for d in detections if mean_side(d.corners) >= self._min_side_px]
        return gray, detections, convert_s

    def convert(self, frame: Frame) -> tuple[Gray, float]:
        """The frame's grey image, and the seconds the conversion took."""
        start = time.perf_counter()
        # a detector in another process offers the buffer it reads from (None: any array), so
        # that the grey image is not copied into it
        gray = to_gray(frame, self.detector.gray_buffer(*frame.pixels.shape[:2]))
        return gray, time.perf_counter() - start

    def look_again(self) -> list[Detection]:
        """The markers the detector's second look adds to the frame :meth:`detect` read last,
        where that look was left until after the frame's tag (see
        :mod:`~zenoh_perception.detect.second_look`); those at least ``min_side_px`` a side.
        Once per frame, after :meth:`detect`."""
        added = self.detector.look_again()
        if self._min_side_px > 0.0 and added:
            added = [d for d in added if mean_side(d.corners) >= self._min_side_px]
        return added

    def screen(self, gray: Gray, detections: list[Detection]) -> list[Detection]:
        """The last steps of :meth:`find`: the verifier's vetoes, then the confirmation."""
        if self._verifier is not None and detections:
            detections, reasons = self._verifier.verify(gray, detections)
            self.vetoed.update(reasons)
        if self._confirmer is not None:
            detections, held = self._confirmer.confirm(gray.shape, detections)
            self.vetoed["unconfirmed"] += held
        return detections

    @property
    def judges_one_by_one(self) -> bool:
        """Whether each detection can be kept or vetoed on its own (:meth:`judge`): with a
        verifier and no confirmation, which needs every detection of the frame at once."""
        return self._verifier is not None and self._confirmer is None

    def judge(self, gray: Gray, detection: Detection) -> str | None:
        """Why the verifier vetoes ``detection``, or None (only when
        :attr:`judges_one_by_one`; a frame's detections are judged after :meth:`start`)."""
        assert self._verifier is not None
        return self._verifier.judge(gray, detection)

    def start(self, gray: Gray) -> None:
        """A frame whose detections are judged one by one begins."""
        assert self._verifier is not None
        self._verifier.start(gray)

    def commit(self, kept: list[Detection], reasons: list[str]) -> None:
        """The frame's detections were all judged: those kept, and each veto's reason."""
        assert self._verifier is not None
        self._verifier.commit(kept)
        self.vetoed.update(reasons)


def detector_for(settings: DetectorSettings, *, wary: bool = False) -> Detector:
    """The detector the settings name: what :class:`Pipeline` runs unless given another (the
    service's deadline runs it in a child process, built there by this function). ``wary``:
    for a detector that replaces one whose read stalled (see
    :func:`~.detect.factory.make_detector`)."""
    return make_detector(
        settings.detector,
        settings.dictionary,
        full_scan_period=settings.full_scan_period,
        wary=wary,
        second_look=settings.second_look,
    )


class Pipeline(TagFinder):
    """Turns decoded frames into an :class:`Analysis`: the settings' :class:`TagFinder`, then
    each tag's geometry and the selection.

    ``intrinsics`` starts from the settings and may be replaced at run time (CameraInfo,
    :meth:`use_camera_info`): a CameraInfo's intrinsics are applied only to frames of its
    image size.
    """

    def __init__(
        self,
        detection: DetectorSettings,
        selection: Selection,
        detector: Detector | None = None,
    ) -> None:
        self.detection, self.selection = detection, selection
        if detector is None:
            detector = detector_for(detection)
        verifier = Verifier(detection.dictionary) if detection.verify else None
        super().__init__(detector, detection.min_tag_side_px, verifier, detection.confirm_frames)
        # one attribute, replaced whole: a frame never sees intrinsics with another's size
        self._camera: tuple[Intrinsics | None, tuple[int, int] | None] = (
            intrinsics_from_settings(selection),
            None,
        )
        self._policy = selection.policy
        self._coarse = coarse_read_for(detection, selection)
        #: the stream's last clear pose of each tag, for its ambiguous poses
        self._poses = PoseMemory()

    @property
    def coarse(self) -> CoarseRead | None:
        """The stream's coarse first read (its counters), or None when the settings leave it
        out (:func:`coarse_read_for`)."""
        return self._coarse

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

    def process(self, frame: Frame) -> Analysis:
        return self.begin(frame).finish()

    def begin(self, frame: Frame) -> Pending:
        """The frame's selected tag, with as little of the verifier's work as that needs:
        candidates are judged in the order the selection ranks them, up to the first kept;
        :meth:`Pending.finish` judges the others. The selection is the one :meth:`process`
        makes, or, with the coarse first read (:mod:`~.detect.coarse`), the one it offers,
        the frame read whole by :meth:`Pending.finish`."""
        start = time.perf_counter()
        converted = self.convert(frame)
        if self._coarse is None:
            return self.begin_whole(frame, converted, start)
        return early_or_whole(self, self._coarse, frame, converted, start)

    def observer(
        self, width: int, height: int
    ) -> tuple[Callable[[Detection], TagObservation], bool]:
        """How a detection of a frame of ``width`` x ``height``, its corners as published, is
        measured, and whether the intrinsics in use were left out for its size."""
        intrinsics, mismatch = self._intrinsics_for(width, height)

        def observed(detection: Detection) -> TagObservation:
            return observe(detection, width, height, self.selection, intrinsics, poses=self._poses)

        return observed, mismatch

    def _intrinsics_for(self, width: int, height: int) -> tuple[Intrinsics | None, bool]:
        """The intrinsics in use for a frame of ``width`` x ``height`` (None where they are
        another size's), and whether they were left out for it."""
        intrinsics, size = self._camera
        mismatch = intrinsics is not None and size is not None and size != (width, height)
        return (None if mismatch else intrinsics), mismatch

    def begin_whole(
        self,
        frame: Frame,
        converted: tuple[Gray, float],
        start: float,
        known: tuple[Detection, Detection] | None = None,
    ) -> Pending:
        """:meth:`begin` on the whole frame, converted already (``start``: when the frame's
        detection time began, :func:`time.perf_counter`). ``known``: a marker of this frame as
        OpenCV read it and as published (refined), which the verifier kept (the coarse first
        read's): where the whole read finds it with those corners, it is neither refined nor
        judged again."""
        gray, detections, convert_s = self.detect(frame, converted)
        width, height = frame.width, frame.height
        intrinsics, mismatch = self._intrinsics_for(width, height)
        refine = self.detection.refine_corners
        published: dict[int, Detection] = {}  # each detection's corners as published
        observations: dict[int, TagObservation] = {}
        verdicts: dict[int, str | None] = {}
        if known is not None:
            again = next((i for i, d in enumerate(detections) if same_read(d, known[0])), None)
            if again is not None:
                published[again] = known[1]
                if self.judges_one_by_one:
                    verdicts[again] = None

        def observe_at(index: int, posed: bool) -> TagObservation:
            if index not in published:
                detection = detections[index]
                published[index] = refined(gray, detection) if refine else detection
            observations[index] = observe(
                published[index],
                width,
                height,
                self.selection,
                intrinsics if posed else None,
                poses=self._poses,
            )
            return observations[index]

        if not (detections and self.judges_one_by_one):
            # no tag before every detection is judged (no verifier, or confirmation): a second
            # look left until after the tag is not taken, since the tag would wait for it
            detections = self.screen(gray, detections)
            tags = tuple(observe_at(i, True) for i in range(len(detections)))
            detect_s = time.perf_counter() - start - convert_s
            analysis = Analysis(
                tags=tags,
                selected=selected_message(tags, width, height, self._policy),
                convert_ms=convert_s * 1e3,
                detect_ms=detect_s * 1e3,
                intrinsics_mismatch=mismatch,
            )
            return Pending(analysis.selected, mismatch, lambda: analysis)
        self.start(gray)
        # A tag is observed (its corners refined, its geometry) only when the selection needs
        # it before the tag, or once it is kept, after the tag: the floors of the others' keys,
        # from OpenCV's corners, say which may rank before it. Poses: with the ``distance``
        # metric the selection reads them, so every detection is observed with its pose before
        # the tag; with ``area`` nothing the tag says depends on a pose, so the poses follow the
        # tag. Either way they are taken in detection order: the stream's pose memory learns
        # from each.
        poses_first = intrinsics is not None and self.selection.metric is Metric.DISTANCE

        def observation(index: int) -> TagObservation:
            if index in observations:
                return observations[index]
            return observe_at(index, poses_first)

        rank = selection_key(width, height, self._policy)
        floors = None
        if poses_first:
            for index in range(len(detections)):
                observation(index)
        else:
            floors = [rank_floor(d, width, height, self._policy, refine=refine) for d in detections]
        selected = NO_TAG
        for index in ranked(len(detections), lambda i: rank(observation(i)), floors):
            if index not in verdicts:
                verdicts[index] = self.judge(gray, detections[index])
            if verdicts[index] is None:
                selected = observation(index).message()
                break
        detect_s = time.perf_counter() - start - convert_s

        def finish() -> Analysis:
            started = time.perf_counter()
            # the second look left until after the tag: smaller markers than the one selected
            added = self.look_again()
            detections.extend(added)
            if poses_first:  # observed in order, as the ones before them
                for index in range(len(detections) - len(added), len(detections)):
                    observation(index)
            elif intrinsics is not None:  # every pose now, in order
                for index in range(len(detections)):
                    observe_at(index, True)
            for index, detection in enumerate(detections):
                if index not in verdicts:
                    verdicts[index] = self.judge(gray, detection)
            kept = [i for i in range(len(detections)) if verdicts[i] is None]
            self.commit(
                [detections[i] for i in kept],
                [reason for reason in verdicts.values() if reason is not None],
            )
            return Analysis(
                tags=tuple(observation(i) for i in kept),
                selected=selected,
                convert_ms=convert_s * 1e3,
                detect_ms=(detect_s + time.perf_counter() - started) * 1e3,
                intrinsics_mismatch=mismatch,
            )

        return Pending(selected, mismatch, finish)


class Pending:
    """A frame whose selected tag is known (publish it first) and whose other detections are
    judged by :meth:`finish`, once."""

    __slots__ = ("_finish", "intrinsics_mismatch", "selected")

    def __init__(
        self, selected: TagMessage, intrinsics_mismatch: bool, finish: Callable[[], Analysis]
    ) -> None:
        self.selected = selected
        #: as :attr:`Analysis.intrinsics_mismatch`
        self.intrinsics_mismatch = intrinsics_mismatch
        self._finish = finish

    def finish(self) -> Analysis:
        """The whole analysis: every detection judged, the verifier's memory and counts
        updated. Call it once, before the next frame of the stream begins."""
        return self._finish()


def same_read(a: Detection, b: Detection) -> bool:
    """Whether OpenCV read ``a`` and ``b`` as one marker: one id of one dictionary, the same
    corners."""
    return (
        a.tag_id == b.tag_id
        and a.dictionary == b.dictionary
        and bool(np.array_equal(a.corners, b.corners))
    )


def coarse_read_for(detection: DetectorSettings, selection: Selection) -> CoarseRead | None:
    """The coarse first read of a stream (:mod:`~.detect.coarse`), where the settings ask for
    it and it gives the whole read's answer: the tag is the largest marker (``closest`` by the
    ``area`` closeness), each marker can be judged alone (no confirmation), and published
    corners are refined (OpenCV's own are a pixel off, whatever resolution found them)."""
    if not (
        detection.coarse_first_read
        and selection.policy == Policy.CLOSEST
        and selection.metric == Metric.AREA
        and detection.confirm_frames == 1
        and detection.refine_corners
    ):
        return None
    return CoarseRead(dictionary_names(detection.dictionary))


def early_or_whole(
    pipeline: Pipeline,
    coarse: CoarseRead,
    frame: Frame,
    converted: tuple[Gray, float],
    start: float,
) -> Pending:
    """:meth:`Pipeline.begin` with the coarse first read: the first of its candidates the veto
    keeps on the full-resolution frame is the tag, and :meth:`Pending.finish` reads the frame
    whole (for the record, and for the next frame's :meth:`CoarseRead.remember`); without
    one, the frame is read whole before its tag."""
    gray = converted[0]
    early: TagObservation | None = None
    known: tuple[Detection, Detection] | None = None  # OpenCV's marker, and as published
    observed, mismatch = pipeline.observer(frame.width, frame.height)
    if coarse.due():
        if pipeline.judges_one_by_one:
            pipeline.start(gray)
        # its reads under the deadline that bounds the detector's (none where it cannot)
        for candidate in coarse.candidates(gray, pipeline.detector.watched):
            # a marker the whole read would drop is not the tag, nor is one vetoed
            if mean_side(candidate.corners) < pipeline.detection.min_tag_side_px or (
                pipeline.judges_one_by_one and pipeline.judge(gray, candidate) is not None
            ):
                continue
            known = (candidate, refined(gray, candidate))  # published on refined corners
            early = observed(known[1])
            break
    coarse_s = time.perf_counter() - start - converted[1]

    def finish(whole: Pending) -> Analysis:
        analysis = whole.finish()
        tag = next((t for t in analysis.tags if t.message() == analysis.selected), None)
        side = 0.0 if tag is None else mean_side(np.asarray(tag.corners))
        coarse.remember(side, [(t.tag_id, t.area_px) for t in analysis.tags])
        if early is None:
            return analysis
        published = early.message()
        differs = not same_answer(published, analysis.selected)
        return replace(
            analysis,
            selected=published,
            detect_ms=analysis.detect_ms + coarse_s * 1e3,
            whole_selected=analysis.selected if differs else None,
        )

    if early is None:
        whole = pipeline.begin_whole(frame, converted, start)
        return Pending(whole.selected, whole.intrinsics_mismatch, lambda: finish(whole))
    # counted as its tag goes out, whatever becomes of the whole read that follows
    coarse.counters["answered"] += 1
    return Pending(
        early.message(),
        mismatch,
        lambda: finish(
            pipeline.begin_whole(frame, converted, time.perf_counter() - converted[1], known)
        ),
    )
