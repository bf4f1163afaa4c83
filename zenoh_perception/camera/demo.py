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
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Final, TextIO

import numpy as np
import zenoh

from zenoh_perception.camera.shm import ShmPutter
from zenoh_perception.errors import MessageDecodeError, PayloadTooLargeError, SettingsError
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.scene import CameraModel, MarkerTruth, Scene, SceneGenerator
from zenoh_perception.service.node import PerceptionService, check_transport_limit
from zenoh_perception.service.skips import Skipped
from zenoh_perception.service.zenoh_args import open_zenoh
from zenoh_perception.settings import FRAME_LIMITS_HINT, Settings
from zenoh_perception.wire.frames import RawFrameMeta, check_payload_size, encode_image_cdr
from zenoh_perception.wire.records import decode_record
from zenoh_perception.wire.text import format_decoded_record

DRIVE_SECONDS = 12.0


#: Frames whose truth is kept while their record is on its way (dropped frames never answer).
MAX_TRUTHS: Final = 64


def drive_forever(resolution: str, fps: float, dictionary: str, seed: int = 0) -> Iterator[Scene]:
    """Endless synthetic drives (a new drive with new tags every ``DRIVE_SECONDS``)."""
    camera = CameraModel.named(resolution)
    generator = SceneGenerator(camera, dictionary=dictionary, seed=seed)
    for _ in itertools.count():
        # at least one frame per drive: an empty drive would loop here for ever
        yield from generator.drive(max(1, round(DRIVE_SECONDS * fps)), fps=fps, speed_mps=0.6)


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


def agreement(record: dict[str, Any], markers: Sequence[MarkerTruth]) -> str:
    """How the record's tags compare with the truth of the frame it answers: tags found, with
    their centre (x, y) and closeness, the largest centre error against the rendered truth
    (px), the visible tags missed and the ids reported where no such tag is."""
    visible = [m for m in markers if m.visible]
    found: list[str] = []
    errors: list[float] = []
    false_ids: list[int] = []
    matched: set[int] = set()
    for tag in record["tags"]:
        x, y = float(tag["x_tag_center_pixel"]), float(tag["y_tag_center_pixel"])
        hits = [
            (float(np.hypot(*(m.corner_mean - (x, y)))), i)
            for i, m in enumerate(markers)
            if m.tag_id == tag["tag_id"] and i not in matched
        ]
        if not hits or min(hits)[0] > max(3.0, 0.3 * markers[min(hits)[1]].side_px):
            false_ids.append(int(tag["tag_id"]))
            continue
        error, index = min(hits)
        matched.add(index)
        errors.append(error)
        found.append(f"{tag['tag_id']}@({x:.1f},{y:.1f}) c={float(tag['closeness_metric']):.3f}")
    missed = sorted(m.tag_id for i, m in enumerate(markers) if m.visible and i not in matched)
    worst = f"{max(errors):.2f}" if errors else "-"
    return (
        f"  truth: {len(visible)} visible; found {' '.join(found) or '-'}; "
        f"centre error <= {worst} px; missed {missed or '-'}; false ids {false_ids or '-'}"
    )


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
    stop: threading.Event | None = None,
    out: TextIO = sys.stdout,
) -> int:
    """Run camera (+ service + echo unless ``camera_only``) until ``stop`` or ``limit`` frames.

    Raises:
        SettingsError: a frame of ``resolution`` exceeds ``settings.max_frame_bytes``, or that
            limit exceeds Zenoh's message limit.
        SessionError: the Zenoh session cannot be opened.

    """
    if not camera_only:
        check_transport_limit(conf, settings)
    stop = stop or threading.Event()
    width, height = RESOLUTIONS[resolution]
    # Every frame holds at least its BGRA pixels: refuse before anything starts.
    check_frame_bytes(
        width * height * 4, settings.max_frame_bytes, f"a {resolution} BGRA demo frame"
    )
    scenes = drive_forever(resolution, fps, settings.dictionary)
    # the truth of the frames put, by stamp, until their record is shown
    truths: dict[int, tuple[MarkerTruth, ...]] = {}
    lock = threading.Lock()

    def remember(stamp_ns: int, scene: Scene) -> None:
        with lock:
            truths[stamp_ns] = scene.markers
            while len(truths) > MAX_TRUTHS:
                del truths[next(iter(truths))]

    with open_zenoh(conf) as session:

        def camera() -> None:
            publish_camera(
                session,
                settings.input_key,
                scenes,
                fps=fps,
                cdr=cdr,
                stop=stop,
                limit=limit,
                shm=shm,
                max_frame_bytes=settings.max_frame_bytes,
                on_frame=None if camera_only else remember,
            )

        if camera_only:
            camera()
            return 0

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
                markers = truths.pop(int(record["stamp_ns"]), None)
            lines = [format_decoded_record(str(sample.key_expr), record, as_json=False)]
            if markers is not None:
                lines.append(agreement(record, markers))
            print("\n".join(lines), file=out, flush=True)

        with PerceptionService(session, settings):
            subscriber = session.declare_subscriber(settings.record_key, show)
            try:
                camera()
                stop.wait(0.5 if limit else 0)  # let the last frame's record arrive
            finally:
                subscriber.undeclare()  # type: ignore[no-untyped-call]
        print(f"demo: {skipped.summary()}", file=sys.stderr, flush=True)
    return 0
