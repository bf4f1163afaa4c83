"""``zenoh-perception demo``: a synthetic camera with moving tags, the service and an echo, in
one process, so a newcomer with no camera sees the whole thing work.

The camera is a rover driving toward tags on posts (``scene.SceneGenerator.drive``), published
on the input key exactly as a real camera would (raw BGRA + msgpack attachment, or
sensor_msgs/Image CDR with ``--format cdr``). With ``--camera-only`` it only publishes, to feed a
``zenoh-perception run`` started elsewhere. With ``--shm`` it puts each frame from a Zenoh
shared-memory buffer (:class:`~zenoh_perception.camera.shm.ShmPutter`), as a camera on the service's
machine would.

A frame larger than the settings' ``max_frame_bytes`` is not sent: the demo refuses the
resolution at start (exit 2, with how to raise the limits), as the service would refuse it.
"""

from __future__ import annotations

import itertools
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final, TextIO

import cv2
import numpy as np
import numpy.typing as npt
import zenoh

from zenoh_perception.camera.shm import ShmPutter, announce
from zenoh_perception.detect.opencv import aruco_detector, read_markers
from zenoh_perception.detect.types import Detection, dictionary_names
from zenoh_perception.errors import MessageDecodeError, PayloadTooLargeError, SettingsError
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.service.session import check_transport_limit
from zenoh_perception.service.skips import Skipped
from zenoh_perception.service.zenoh_args import open_zenoh
from zenoh_perception.settings import FRAME_LIMITS_HINT, Settings
from zenoh_perception.tags.selection import Policy
from zenoh_perception.wire.frames import RawFrameMeta, check_payload_size, encode_image_cdr
from zenoh_perception.wire.records import decode_record
from zenoh_perception.wire.stream_keys import has_wildcard
from zenoh_perception.wire.text import format_decoded_record
from zenoh_perception_bench import surroundings
from zenoh_perception_bench.scene import (
    CameraModel,
    DistractorTruth,
    MarkerTruth,
    Scene,
    SceneGenerator,
)

DRIVE_SECONDS = 12.0
#: Edge lengths of the demo's tags, metres (drawn per tag).
DEMO_TAG_SIZE_M: Final = (0.3, 0.45)


#: Frames whose truth is kept while their record is on its way (dropped frames never answer).
MAX_TRUTHS: Final = 64


def drive_forever(
    resolution: str,
    fps: float,
    dictionary: str,
    seed: int = 0,
    *,
    adversaries: bool = False,
    bands: Sequence[npt.NDArray[np.uint8]] | None = None,
) -> Iterator[Scene]:
    """Endless synthetic drives (a new drive with new tags every ``DRIVE_SECONDS``), past
    what a rover meets (``bands``: :func:`~zenoh_perception_bench.surroundings.layers`, one
    a drive in turn; drawn here when None), or with ``adversaries`` past the generator's
    synthetic look-alikes instead."""
    camera = CameraModel.named(resolution)
    generator = SceneGenerator(camera, dictionary=dictionary, seed=seed)
    if not adversaries and bands is None:
        first = dictionary.split(",", maxsplit=1)[0].strip()
        bands = surroundings.layers(first, camera.width, camera.height, seed)
    for drive in itertools.count():
        # tags large enough to be read from most of the drive; the far ones are said to be;
        # at least one frame per drive: an empty drive would loop here for ever
        scenes = generator.drive(
            max(1, round(DRIVE_SECONDS * fps)),
            fps=fps,
            speed_mps=0.6,
            size_m=DEMO_TAG_SIZE_M,
            n_distractors=2 if adversaries else 0,
        )
        if not bands:
            yield from scenes
            continue
        band = bands[drive % len(bands)]
        for scene in scenes:
            yield replace(scene, image=surroundings.composed(scene.image, band, scene.markers))


def check_frame_bytes(size: int, max_frame_bytes: int, what: str) -> None:
    """Refuse (camera side) a frame of ``size`` bytes that the service would refuse.

    Raises:
        SettingsError: ``size`` exceeds ``max_frame_bytes``; the message says how to raise it.

    """
    try:
        check_payload_size(size, max_frame_bytes)
    except PayloadTooLargeError as err:
        msg = (
            f"{what} is {size} bytes, over max_frame_bytes = {max_frame_bytes}: the service "
            f"would refuse it; {FRAME_LIMITS_HINT}"
        )
        raise SettingsError(msg) from err


#: Mean side (px) under which a tag is too small for OpenCV's default detector to read: its
#: 4x4 cells plus border are then under about 1.5 px each.
MIN_READABLE_SIDE_PX: Final = 10.0


@dataclass(frozen=True, slots=True)
class Agreement:
    """How one record compares with the truth of the frame it answers."""

    in_view: int  # tags whose four corners are inside the frame
    read: tuple[tuple[int, float], ...]  # (id, centre error in px) of each tag found
    not_read: tuple[tuple[int, str], ...]  # (id, why) of each tag in view that was not found
    false_ids: tuple[int, ...]  # ids reported where no such tag is
    on_lookalikes: tuple[int, ...] = ()  # those of them read on the scene's look-alikes
    selected_false: bool = False  # the selected tag, what a rover steers by, is a false id

    @staticmethod
    def why_not_read(marker: MarkerTruth) -> str:
        if marker.occluded:
            return "hidden"
        if marker.side_px < MIN_READABLE_SIDE_PX:
            return "too far"
        return "other"


def _near(truth: MarkerTruth | DistractorTruth, x: float, y: float) -> float | None:
    """Distance from (x, y) to ``truth``'s corner mean, when within 3 px or 30 % of its side."""
    distance = float(np.hypot(*(truth.corners.mean(axis=0) - (x, y))))
    return distance if distance <= max(3.0, 0.3 * truth.side_px) else None


def agreement(
    record: dict[str, Any],
    markers: Sequence[MarkerTruth],
    distractors: Sequence[DistractorTruth] = (),
) -> Agreement:
    """Match the record's tags with the rendered truth: a tag is read when a tag of its id
    lies within 3 px (or 30 % of its side) of where the record puts it; a false id is on a
    look-alike when one carrying that id's code lies there."""
    read: list[tuple[int, float]] = []
    false_ids: list[int] = []
    lookalikes: list[int] = []
    matched: set[int] = set()
    for tag in record["tags"]:
        tag_id = int(tag["tag_id"])
        x, y = float(tag["x_tag_center_pixel"]), float(tag["y_tag_center_pixel"])
        hits = [
            (distance, i)
            for i, m in enumerate(markers)
            if m.tag_id == tag_id and i not in matched and (distance := _near(m, x, y)) is not None
        ]
        if not hits:
            false_ids.append(tag_id)
            if any(d.mimic_id == tag_id and _near(d, x, y) is not None for d in distractors):
                lookalikes.append(tag_id)
            continue
        error, index = min(hits)
        matched.add(index)
        read.append((tag_id, error))
    not_read = tuple(
        (m.tag_id, Agreement.why_not_read(m))
        for i, m in enumerate(markers)
        if m.visible and i not in matched
    )
    in_view = sum(m.visible for m in markers)
    chosen = record.get("selected") or {}
    chosen_id = int(chosen.get("tag_id", -1))
    selected_false = chosen_id >= 0 and not any(
        m.tag_id == chosen_id
        and _near(m, float(chosen["x_tag_center_pixel"]), float(chosen["y_tag_center_pixel"]))
        is not None
        for m in markers
    )
    return Agreement(
        in_view, tuple(read), not_read, tuple(false_ids), tuple(lookalikes), selected_false
    )


_WHY: Final = {
    "hidden": "partly hidden by a nearer object",
    "too far": f"too far: under {MIN_READABLE_SIDE_PX:.0f} px a side",
    "other": "not read (blur, angle or light)",
}


def format_agreement(result: Agreement, markers: Sequence[MarkerTruth]) -> str:
    """The truth line printed under each record."""
    sides = {m.tag_id: m.side_px for m in markers}
    read = ", ".join(f"{tag_id} ({error:.2f} px off)" for tag_id, error in result.read)
    not_read = ", ".join(
        f"{tag_id} ({sides[tag_id]:.0f} px, {_WHY[why]})" for tag_id, why in result.not_read
    )
    false = "no false id"
    if result.false_ids:
        false = f"reported where no such tag is: {list(result.false_ids)}"
        if result.on_lookalikes:
            false += f" ({len(result.on_lookalikes)} on the scene's look-alikes)"
    return (
        f"  truth: {result.in_view} tags in view; read {read or 'none'}; "
        f"not read {not_read or 'none'}; {false}"
    )


@dataclass(slots=True)
class Summary:
    """The whole run's agreement, printed when the demo ends."""

    frames: int = 0
    in_view: int = 0
    read: int = 0
    not_read: Counter[str] = field(default_factory=Counter)
    false_ids: int = 0
    on_lookalikes: int = 0
    selected_false: int = 0  # frames whose selected tag was a false id
    #: OpenCV's default detector on the same frames, selecting by the same policy
    opencv: Summary | None = None

    def add(self, result: Agreement) -> None:
        self.frames += 1
        self.in_view += result.in_view
        self.read += len(result.read)
        self.not_read.update(why for _tag_id, why in result.not_read)
        self.false_ids += len(result.false_ids)
        self.on_lookalikes += len(result.on_lookalikes)
        self.selected_false += result.selected_false

    def format(self, sent: int) -> str:
        share = f" ({100 * self.read / self.in_view:.0f} %)" if self.in_view else ""
        reasons = ", ".join(f"{why} {self.not_read[why]}" for why in _WHY if self.not_read[why])
        return (
            f"demo: {self.frames} of {sent} frames answered (the newest frame wins: a busy "
            f"machine skips some); {self.in_view} tags in view, {self.read} read{share}, "
            f"{sum(self.not_read.values())} not read{f' ({reasons})' if reasons else ''}; "
            f"{self.false_ids} false ids{self._lookalike_note()}, "
            f"{self.selected_false} selected (the tag a rover steers by) where no such tag is"
            + self._opencv_line()
        )

    def _opencv_line(self) -> str:
        if self.opencv is None:
            return ""
        o = self.opencv
        return (
            f"\ndemo: OpenCV's default detector on the same {o.frames} frames: {o.read} read, "
            f"{o.false_ids} false ids, {o.selected_false} selected where no such tag is "
            "(what the service's checks veto)"
        )

    def _lookalike_note(self) -> str:
        if not self.on_lookalikes:
            return ""
        return (
            f" ({self.on_lookalikes} on the scene's look-alikes: shapes that carry a valid "
            "code, which OpenCV's decoder accepts)"
        )


class OpenCvDefault:
    """OpenCV's ArUco detector with its default parameters, reading the demo's frames as a
    record would report them (the selected tag by the service's policy: the largest for
    ``closest``, the nearest the centre for ``center``)."""

    def __init__(self, dictionary: str, policy: Policy) -> None:
        self._dictionaries = tuple(dictionary_names(dictionary))
        self._detector = aruco_detector(self._dictionaries, cv2.aruco.DetectorParameters())
        self._centre = policy is Policy.CENTER

    def record(self, image: npt.NDArray[np.uint8]) -> dict[str, Any]:
        grey = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
        found, _ = read_markers(self._detector, grey, self._dictionaries)
        tags = [_tag_fields(d) for d in found]
        if not tags:
            return {"tags": [], "selected": None}
        height, width = grey.shape

        def rank(pair: tuple[Detection, dict[str, Any]]) -> float:
            detection, tag = pair
            if self._centre:
                x, y = tag["x_tag_center_pixel"], tag["y_tag_center_pixel"]
                return float(np.hypot(x - width / 2, y - height / 2))
            return -float(cv2.contourArea(detection.corners))

        _, chosen = min(zip(found, tags, strict=True), key=rank)
        return {"tags": tags, "selected": chosen}


def _tag_fields(detection: Detection) -> dict[str, Any]:
    x, y = detection.corners.mean(axis=0)
    return {"tag_id": detection.tag_id, "x_tag_center_pixel": x, "y_tag_center_pixel": y}


def publish_camera(
    session: zenoh.Session,
    key: str,
    scenes: Iterator[Scene],
    *,
    fps: float,
    cdr: bool,
    stop: threading.Event,
    limit: int = 0,
    shm: bool = False,
    max_frame_bytes: int | None = None,
    on_frame: Callable[[int, Scene], None] | None = None,
) -> int:
    """Publish ``scenes`` at ``fps`` until ``stop`` (or ``limit`` frames); returns frames sent.
    With ``shm``, frames go from a Zenoh shared-memory buffer (plain puts if unavailable).
    ``on_frame(stamp_ns, scene)`` is called before each frame is put.

    Raises:
        SettingsError: a frame exceeds ``max_frame_bytes`` (None: no limit).

    """
    publisher = session.declare_publisher(key)
    token = announce(session, key)  # the stream, for instances that share the streams
    putter = ShmPutter() if shm else None
    period = 1.0 / fps
    next_at = time.monotonic()
    sent = 0
    try:
        for seq, scene in enumerate(scenes):
            if stop.is_set() or (limit and sent >= limit):
                break
            stamp_ns = time.time_ns()
            attachment = None
            if cdr:
                payload = bytes(
                    encode_image_cdr(scene.image, "bgra8", stamp_ns=stamp_ns, frame_id="demo")
                )
            else:
                height, width = scene.image.shape[:2]
                meta = RawFrameMeta(width, height, stamp_ns=stamp_ns, frame_id="demo", seq=seq)
                payload, attachment = scene.image.tobytes(), meta.to_msgpack()
            if max_frame_bytes is not None:
                check_frame_bytes(len(payload), max_frame_bytes, f"demo frame {seq + 1}")
            if on_frame is not None:
                on_frame(stamp_ns, scene)
            if putter is None:
                publisher.put(payload, attachment=attachment)
            else:
                putter.put(publisher, payload, attachment=attachment)
            sent += 1
            next_at += period
            delay = next_at - time.monotonic()
            if delay > 0:
                stop.wait(delay)
            else:
                next_at = time.monotonic()  # rendering is slower than fps: do not try to catch up
    finally:
        token.undeclare()  # type: ignore[no-untyped-call]
        publisher.undeclare()  # type: ignore[no-untyped-call]
    return sent


def main(
    conf: zenoh.Config,
    settings: Settings,
    *,
    resolution: str = "VGA",
    fps: float = 15.0,
    cdr: bool = False,
    camera_only: bool = False,
    limit: int = 0,
    shm: bool = False,
    adversaries: bool = False,
    stop: threading.Event | None = None,
    out: TextIO = sys.stdout,
) -> int:
    """Run camera (+ service + echo unless ``camera_only``) until ``stop`` or ``limit`` frames.

    Raises:
        SettingsError: a frame of ``resolution`` exceeds ``max_frame_bytes``, or that limit
            exceeds Zenoh's message limit; ``input_key``, which the camera publishes on,
            holds a wildcard or is a list.
        SessionError: the Zenoh session cannot be opened.

    """
    if not isinstance(settings.inputs.input_key, str) or has_wildcard(settings.inputs.input_key):
        key = settings.inputs.input_key
        shown, what = (key, "wildcard") if isinstance(key, str) else (list(key), "list")
        msg = (
            f"input_key = {shown!r}: the demo's camera publishes on it, so it must be one "
            f"camera's key (e.g. 'rover/front/image'); run the service on the {what} apart"
        )
        raise SettingsError(msg)
    input_key = settings.inputs.input_key
    if not camera_only:
        check_transport_limit(conf, settings.limits)
    stop = stop or threading.Event()
    width, height = RESOLUTIONS[resolution]
    # Every frame holds at least its BGRA pixels: refuse before anything starts.
    check_frame_bytes(
        width * height * 4, settings.limits.max_frame_bytes, f"a {resolution} BGRA demo frame"
    )
    # what the rover passes, drawn before the service starts: too long to draw between frames
    first = dictionary_names(settings.detection.dictionary)[0]
    bands = () if adversaries else surroundings.layers(first, width, height)
    scenes = drive_forever(
        resolution, fps, settings.detection.dictionary, adversaries=adversaries, bands=bands
    )
    # the truth of the frames put, by stamp, and what OpenCV's default read on them, until
    # their record is shown
    truths: dict[int, tuple[Scene, Agreement]] = {}
    lock = threading.Lock()
    opencv = (
        None
        if camera_only
        else OpenCvDefault(settings.detection.dictionary, settings.selection.policy)
    )

    def remember(stamp_ns: int, scene: Scene) -> None:
        assert opencv is not None  # remembered only beside the service
        baseline = agreement(opencv.record(scene.image), scene.markers, scene.distractors)
        with lock:
            truths[stamp_ns] = (scene, baseline)
            while len(truths) > MAX_TRUTHS:
                del truths[next(iter(truths))]

    with open_zenoh(conf) as session:

        def camera() -> int:
            return publish_camera(
                session,
                input_key,
                scenes,
                fps=fps,
                cdr=cdr,
                stop=stop,
                limit=limit,
                shm=shm,
                max_frame_bytes=settings.limits.max_frame_bytes,
                on_frame=None if camera_only else remember,
            )

        if camera_only:
            camera()
            return 0

        summary = Summary(opencv=Summary())
        skipped = Skipped()

        def show(sample: zenoh.Sample) -> None:
            # anyone may publish on the record key: what is no record is skipped and counted
            try:
                record = decode_record(sample.payload.to_bytes())
            except MessageDecodeError as err:
                line = skipped.skip(str(sample.key_expr), err, as_json=False)
                if line is not None:
                    print(line, file=out, flush=True)
                return
            with lock:
                truth = truths.pop(int(record["stamp_ns"]), None)
            lines = [format_decoded_record(str(sample.key_expr), record, as_json=False)]
            if truth is not None:
                scene, baseline = truth
                result = agreement(record, scene.markers, scene.distractors)
                with lock:
                    summary.add(result)
                    if summary.opencv is not None:  # paired: the frames the service answered
                        summary.opencv.add(baseline)
                lines.append(format_agreement(result, scene.markers))
            print("\n".join(lines), file=out, flush=True)

        with PerceptionService(session, settings):
            subscriber = session.declare_subscriber(settings.outputs.record_key, show)
            sent = 0
            try:
                sent = camera()
                stop.wait(0.5 if limit else 0)  # let the last frame's record arrive
            finally:
                subscriber.undeclare()  # type: ignore[no-untyped-call]
            with lock:
                print(summary.format(sent), file=out, flush=True)
        print(f"demo: {skipped.summary()}", file=sys.stderr, flush=True)
    return 0
