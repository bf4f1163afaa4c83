"""``zenoh-perception replay PATH``: publish recorded frames into Zenoh as a camera would.

The frames come from :mod:`zenoh_perception.camera.sources` (rosbag2, video, images). This module
holds the pure pacing and progress-bar code, the Zenoh publishing loop (:func:`main`) and the
options it takes from the ``replay`` flags (:func:`options_from_args`; the flags themselves are
declared in :mod:`zenoh_perception.cli.commands`).

Pacing: ``recorded`` follows the sources' recording clock (bag receive times, video FPS, image
rate), ``rate`` sends at a fixed rate, ``asap`` as fast as Zenoh takes them. The publisher uses
congestion control BLOCK, so a slow link slows the replay instead of dropping frames.

``--shm`` publishes each frame from a Zenoh shared-memory buffer (:class:`ShmPutter`), as a
camera on the service's machine would: no copy on put, the service reads the frame in place.
Without shared memory it falls back to plain puts and says so in the log.

``--compressed jpeg|png`` publishes every frame as sensor_msgs/msg/CompressedImage CDR, as
image_transport's compressed plugin would (on ``zed/left/image/compressed`` unless ``--key``
says otherwise), with the frame's stamp and frame id.

While it runs, the replay announces its key with a liveliness token at ``@camera/<key>``
(:func:`~zenoh_perception.camera.shm.announce`): instances that share the streams
(``share_group``) subscribe to it once they see that, and only the one given the stream does.

A frame larger than ``--max-frame-bytes`` (the service's ``max_frame_bytes`` default) is not
sent: the replay stops with exit 2 and says how to raise the limits, rather than feed a
service that would refuse every such frame.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from contextlib import closing
from dataclasses import dataclass
from enum import StrEnum
from typing import Final, TextIO

import zenoh

from zenoh_perception.camera import readers
from zenoh_perception.camera.defaults import DEFAULT_COMPRESSED_KEY, DEFAULT_KEY
from zenoh_perception.camera.readers import ANSWER_S
from zenoh_perception.camera.shm import ShmPutter, announce
from zenoh_perception.camera.sources import (
    FrameSource,
    ImageSequenceSource,
    ReplayError,
    SourceFrame,
)
from zenoh_perception.errors import FrameDecodeError, PayloadTooLargeError, SettingsError
from zenoh_perception.service.logs import kv
from zenoh_perception.service.zenoh_args import (
    open_zenoh,
)
from zenoh_perception.settings import FRAME_LIMITS_HINT, Settings
from zenoh_perception.wire.compressed import CODECS, Codec, encode_compressed_frame
from zenoh_perception.wire.frames import (
    MAX_FRAME_ID_CHARS,
    check_payload_size,
    decode_image_cdr,
    decode_raw_frame,
)

log = logging.getLogger("zenoh_perception.camera.replay")

_RAW_ENCODING: Final = zenoh.Encoding.APPLICATION_OCTET_STREAM
_CDR_ENCODING: Final = zenoh.Encoding.APPLICATION_CDR
_WAIT_POLL_S: Final = 0.1
#: Seconds between two lines of a camera waiting for a subscriber.
_WAITING_EVERY_S: Final = 10.0

Clock = Callable[[], float]


class Pacing(StrEnum):
    RECORDED = "recorded"
    RATE = "rate"
    ASAP = "asap"


# -- pure: pacing ----------------------------------------------------------------------------


#: Longest wait between two frames of a recording, s: a longer recorded gap is cut to it.
MAX_GAP_S: Final = 5.0


class Pacer:
    """When each frame is due, on a monotonic clock in seconds read by the caller.

    ``recorded`` keeps the spacing of the frames' recording stamps; ``rate`` spaces frames
    ``1 / rate_hz`` apart; ``asap`` makes every frame due at once. Deadlines are measured from an
    anchor (no drift). The anchor moves when the recording clock jumps back (a new ``--loop``
    pass continues one interval after the last frame) or when sending lags more than
    ``max_lag_s`` behind (then frames are not sent in a burst to catch up).
    """

    def __init__(
        self,
        pacing: Pacing,
        rate_hz: float | None = None,
        *,
        max_lag_s: float = 1.0,
        max_gap_s: float = MAX_GAP_S,
    ) -> None:
        if pacing is Pacing.RATE and (
            rate_hz is None or not math.isfinite(rate_hz) or rate_hz <= 0
        ):
            msg = f"fixed-rate pacing needs a positive rate, not {rate_hz!r}"
            raise ReplayError(msg)
        self.pacing = pacing
        self._period_s = 1.0 / rate_hz if rate_hz else 0.0
        self._max_lag_s = max_lag_s
        self._max_gap_s = max_gap_s
        #: Recorded gaps longer than ``max_gap_s`` that were cut to it, and the last one, s.
        self.capped_gaps = 0
        self.last_gap_s = 0.0
        self._anchor_s: float | None = None
        self._anchor_stamp = 0
        self._count = 0
        self._last_stamp = 0
        self._last_due = 0.0
        self._interval_s = 0.0

    def due(self, stamp_ns: int, now: float) -> float:
        """The clock time at which the frame stamped ``stamp_ns`` should be sent."""
        if self.pacing is Pacing.ASAP:
            return now
        if self._anchor_s is None:
            self._reanchor(now, stamp_ns)
        elif self.pacing is Pacing.RECORDED and stamp_ns < self._last_stamp:
            self._reanchor(max(now, self._last_due + self._interval_s), stamp_ns)
        elif (
            self.pacing is Pacing.RECORDED
            and (gap_s := (stamp_ns - self._last_stamp) / 1e9) > self._max_gap_s
        ):
            # a recording clock that jumps forward (a paused recorder, a corrupt time) would
            # hold the next frame back for as long: the wait is cut to max_gap_s
            self._reanchor(self._last_due + self._max_gap_s, stamp_ns)
            self.capped_gaps += 1
            self.last_gap_s = gap_s
        due = self._target(stamp_ns)
        if due < now - self._max_lag_s:
            self._reanchor(now, stamp_ns)
            due = now
        if self.pacing is Pacing.RECORDED and stamp_ns > self._last_stamp and self._count:
            self._interval_s = (stamp_ns - self._last_stamp) / 1e9
        self._count += 1
        self._last_stamp = stamp_ns
        self._last_due = due
        return due

    def _reanchor(self, at: float, stamp_ns: int) -> None:
        self._anchor_s = at
        self._anchor_stamp = stamp_ns
        self._count = 0

    def _target(self, stamp_ns: int) -> float:
        anchor = self._anchor_s if self._anchor_s is not None else 0.0
        if self.pacing is Pacing.RATE:
            return anchor + self._count * self._period_s
        return anchor + (stamp_ns - self._anchor_stamp) / 1e9


# -- pure: progress bar ----------------------------------------------------------------------


def render_progress(done: int, total: int | None, elapsed_s: float, *, width: int = 30) -> str:
    """One progress line: a bar when ``total`` is known, the count and the mean frame rate
    (``elapsed_s`` is the time since the first frame was sent)."""
    fps = (done - 1) / elapsed_s if done > 1 and elapsed_s > 0 else 0.0
    if total:
        filled = min(width, done * width // total)
        bar = "#" * filled + "." * (width - filled)
        percent = min(100, done * 100 // total)
        return f"replay [{bar}] {percent:3d}% {done}/{total} frames {fps:.1f} fps"
    return f"replay {done} frames {fps:.1f} fps"


class ProgressBar:
    """Redraws :func:`render_progress` in place (carriage return) at most every
    ``min_interval_s``; :meth:`finish` draws the final state and ends the line. The clock
    starts at the first :meth:`update` (the first frame sent)."""

    def __init__(self, stream: TextIO, total: int | None, *, min_interval_s: float = 0.2) -> None:
        self._stream = stream
        self._total = total
        self._start: float | None = None
        self._min_interval_s = min_interval_s
        self._last_draw: float | None = None
        self._width = 0

    def update(self, done: int, now: float) -> None:
        if self._last_draw is not None and now - self._last_draw < self._min_interval_s:
            return
        self._draw(done, now)

    def finish(self, done: int, now: float) -> None:
        self._draw(done, now)
        self._stream.write("\n")
        self._stream.flush()

    def _draw(self, done: int, now: float) -> None:
        if self._start is None:
            self._start = now
        self._last_draw = now
        line = render_progress(done, self._total, now - self._start)
        # Pad with spaces so a shorter line fully covers the previous one.
        self._stream.write("\r" + line.ljust(self._width))
        self._stream.flush()
        self._width = len(line)


# -- pure: compression ----------------------------------------------------------------------


def compress_frame(frame: SourceFrame, codec: Codec) -> SourceFrame:
    """``frame`` (raw with its attachment, or Image CDR) as CompressedImage CDR, keeping its
    stamp and frame id (a raw frame without a stamp gets its recording-clock time).

    Raises:
        ReplayError: the frame cannot be decoded (an encoding the service does not read).

    """
    try:
        if frame.attachment is None:
            decoded = decode_image_cdr(frame.payload)
        else:
            decoded = decode_raw_frame(frame.payload, frame.attachment)
    except FrameDecodeError as err:
        msg = f"cannot compress a frame: {err}"
        raise ReplayError(msg) from err
    stamp_ns = decoded.stamp_ns if decoded.stamp_ns is not None else frame.stamp_ns
    payload = encode_compressed_frame(decoded, codec, stamp_ns=stamp_ns, frame_id=decoded.frame_id)
    return SourceFrame(bytes(payload), None, frame.stamp_ns)


# -- the Zenoh publishing loop ---------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ReplayOptions:
    """How :func:`main` publishes a source (the ``replay`` flags, parsed)."""

    key: str = DEFAULT_KEY
    pacing: Pacing = Pacing.RECORDED
    rate_hz: float | None = None
    loop: bool = False
    limit: int = 0  # frames in total; 0 = no limit
    wait_for_subscriber: bool = True
    subscriber_timeout_s: float | None = None  # None = wait until stopped
    progress: bool = False
    shm: bool = False  # put frames from a Zenoh shared-memory buffer
    max_frame_bytes: int = Settings().limits.max_frame_bytes  # larger frames stop the replay
    compressed: Codec | None = None  # publish CompressedImage CDR of this codec


def _is_matching(publisher: zenoh.Publisher) -> bool:
    # zenoh-python 1.x returns a MatchingStatus here although its stub says bool.
    status: object = publisher.matching_status
    return bool(getattr(status, "matching", status))


def _wait_for_subscriber(
    session: zenoh.Session,
    publisher: zenoh.Publisher,
    *,
    timeout_s: float | None,
    stop: threading.Event,
    clock: Clock,
) -> bool:
    """True once ``publisher`` has a matching subscriber; False on timeout or stop. Until
    then, every :data:`_WAITING_EVERY_S` a line says which services run and what they read."""
    matched = threading.Event()

    def on_status(status: zenoh.MatchingStatus) -> None:
        if status.matching:
            matched.set()

    with publisher.declare_matching_listener(on_status):
        if _is_matching(publisher):
            return True
        deadline = None if timeout_s is None else clock() + timeout_s
        say_at = clock()
        while not stop.is_set():
            if clock() >= say_at:
                say_at = clock() + _WAITING_EVERY_S
                left = ANSWER_S if deadline is None else min(ANSWER_S, deadline - clock())
                statuses = readers.ask(session, max(left, 0.01))
                fields = readers.waiting_fields(str(publisher.key_expr), statuses)
                if matched.is_set():
                    return True
                log.info(
                    "event=replay_waiting key=%s reason=no_subscriber %s",
                    publisher.key_expr,
                    fields,
                )
            wait = _WAIT_POLL_S if deadline is None else min(_WAIT_POLL_S, deadline - clock())
            if wait <= 0:
                return False
            if matched.wait(wait):
                return True
        return False


def _publish_all(
    publisher: zenoh.Publisher,
    source: FrameSource,
    options: ReplayOptions,
    *,
    stop: threading.Event,
    clock: Clock,
    progress: ProgressBar | None,
    putter: ShmPutter | None = None,
) -> int:
    """Publish passes of ``source`` until done, stopped or at the limit; frames published."""
    pacer = Pacer(options.pacing, options.rate_hz)
    published = 0
    while not stop.is_set():
        sent_this_pass = 0
        frames = source.frames(epoch_ns=time.time_ns(), seq_start=published)
        with closing(frames):
            for source_frame in frames:
                frame = (
                    source_frame
                    if options.compressed is None
                    else compress_frame(source_frame, options.compressed)
                )
                _check_frame_size(frame, published + 1, source, options.max_frame_bytes)
                if not _send(publisher, frame, pacer=pacer, stop=stop, clock=clock, putter=putter):
                    return published
                published += 1
                sent_this_pass += 1
                if progress is not None:
                    progress.update(published, clock())
                if options.limit and published >= options.limit:
                    return published
        if not options.loop or sent_this_pass == 0:
            break
    return published


def _check_frame_size(frame: SourceFrame, number: int, source: FrameSource, limit: int) -> None:
    """Refuse to send a frame the service would refuse for its size.

    Raises:
        ReplayError: the frame's payload exceeds ``limit`` bytes.

    """
    try:
        check_payload_size(len(frame.payload), limit)
    except PayloadTooLargeError as err:
        msg = (
            f"frame {number} of the {source.kind} is {len(frame.payload)} bytes, over "
            f"max_frame_bytes = {limit}: the service would refuse it; {FRAME_LIMITS_HINT}"
        )
        raise ReplayError(msg) from err


def _send(
    publisher: zenoh.Publisher,
    frame: SourceFrame,
    *,
    pacer: Pacer,
    stop: threading.Event,
    clock: Clock,
    putter: ShmPutter | None = None,
) -> bool:
    """Wait until ``frame`` is due, then put it (from shared memory with ``putter``); False
    when stopped first."""
    capped = pacer.capped_gaps
    delay = pacer.due(frame.stamp_ns, clock()) - clock()
    if pacer.capped_gaps != capped:
        log.warning(
            "event=replay_gap_capped gap_s=%.3f waited_s=%.1f detail=%s",
            pacer.last_gap_s,
            MAX_GAP_S,
            '"the recording\'s clock jumps forward: the wait is cut"',
        )
    if (delay > 0 and stop.wait(delay)) or stop.is_set():
        return False
    payload = frame.payload if putter is None else putter.load(frame.payload)
    if frame.attachment is None:
        publisher.put(payload, encoding=_CDR_ENCODING)
    else:
        publisher.put(payload, encoding=_RAW_ENCODING, attachment=frame.attachment)
    return True


def main(
    conf: zenoh.Config,
    source: FrameSource,
    options: ReplayOptions,
    stop: threading.Event,
    *,
    progress_stream: TextIO | None = None,
    clock: Clock = time.monotonic,
) -> int:
    """Open a session with ``conf`` and publish ``source`` on ``options.key``; 0 when done or
    stopped.

    Raises:
        ReplayError: no subscriber matched within ``options.subscriber_timeout_s``, the source
            failed while being read, or a frame exceeds ``options.max_frame_bytes``.
        SessionError: the Zenoh session cannot be opened.

    """
    total = options.limit or None
    if not options.loop and source.count is not None:
        total = min(total, source.count) if total else source.count
    with (
        open_zenoh(conf) as session,
        session.declare_publisher(
            options.key, congestion_control=zenoh.CongestionControl.BLOCK
        ) as publisher,
        # announced before the wait: a service of a share group subscribes to this key only
        # once it has seen the announcement
        announce(session, options.key),
    ):
        if options.wait_for_subscriber and not _wait_for_subscriber(
            session, publisher, timeout_s=options.subscriber_timeout_s, stop=stop, clock=clock
        ):
            if stop.is_set():
                return 0
            msg = (
                f"no subscriber on {options.key!r} within "
                f"{options.subscriber_timeout_s} s (is the service running and connected?)"
            )
            raise ReplayError(msg)
        skipped = source.skipped if isinstance(source, ImageSequenceSource) else ()
        if skipped:
            # a folder of images replays its images only: say what it leaves out (a video
            # in it is replayed by naming the video itself)
            log.warning(
                "event=replay_skipped_files %s",
                kv(
                    count=len(skipped),
                    files=",".join(p.name for p in skipped[:10]),
                    detail="not images: left out of the sequence (replay a video by its path)",
                ),
            )
        log.info(
            "event=replay_started source=%s frames=%s key=%s pacing=%s loop=%s limit=%d shm=%s "
            "compressed=%s",
            source.kind,
            source.count if source.count is not None else "unknown",
            options.key,
            options.pacing,
            options.loop,
            options.limit,
            options.shm,
            options.compressed or "no",
        )
        start = clock()
        stream = progress_stream if progress_stream is not None else sys.stderr
        progress = ProgressBar(stream, total) if options.progress else None
        putter = ShmPutter() if options.shm else None
        published = _publish_all(
            publisher, source, options, stop=stop, clock=clock, progress=progress, putter=putter
        )
        if progress is not None:
            progress.finish(published, clock())
        _report_shortfall(source, options, published, total, stopped=stop.is_set())
        shm = (
            ""
            if putter is None
            else f" shm_frames={putter.shm_frames} plain_frames={putter.plain_frames}"
        )
        log.info(
            "event=replay_done published=%d stopped=%s seconds=%.2f%s",
            published,
            stop.is_set(),
            clock() - start,
            shm,
        )
    return 0


def check_frame_id(name: str, value: str) -> str:
    """``value`` when the service would accept it as a frame's ``frame_id``.

    Raises:
        SettingsError: over MAX_FRAME_ID_CHARS characters, or a control character in it.

    """
    if len(value) > MAX_FRAME_ID_CHARS or any(
        ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F for c in value
    ):
        msg = (
            f"{name} must be at most {MAX_FRAME_ID_CHARS} characters without control "
            f"characters (the service rejects other frames), not {len(value)} characters"
        )
        raise SettingsError(msg)
    return value


def _report_shortfall(
    source: FrameSource,
    options: ReplayOptions,
    published: int,
    total: int | None,
    *,
    stopped: bool,
) -> None:
    """Say which frames were not sent and why; nothing sent at all is an error.

    Raises:
        ReplayError: not stopped, and not one frame could be read from the source.

    """
    if stopped:
        return
    if published == 0:
        msg = (
            f"sent no frame: the {source.kind} yielded none "
            f"(announced: {source.count if source.count is not None else 'unknown'}); "
            "is it empty, truncated or corrupt?"
        )
        raise ReplayError(msg)
    if total is not None and not options.loop and published < total:
        log.warning(
            "event=replay_incomplete published=%d announced=%d unsent=%d detail=%s",
            published,
            total,
            total - published,
            f'"the {source.kind} ended early: the frames after {published} could not be read '
            '(truncated or corrupt)"',
        )


def options_from_args(args: argparse.Namespace, *, stderr_is_tty: bool) -> ReplayOptions:
    if args.as_fast_as_possible:
        pacing = Pacing.ASAP
    elif args.rate is not None:
        pacing = Pacing.RATE
    else:
        pacing = Pacing.RECORDED
    compressed: Codec | None = None
    for codec in CODECS:
        if args.compressed == codec:
            compressed = codec
    key = args.key
    if key is None:
        key = DEFAULT_KEY if compressed is None else DEFAULT_COMPRESSED_KEY
    return ReplayOptions(
        key=key,
        pacing=pacing,
        rate_hz=args.rate,
        loop=args.loop,
        limit=args.limit,
        wait_for_subscriber=args.wait_for_subscriber,
        subscriber_timeout_s=args.subscriber_timeout,
        progress=stderr_is_tty if args.progress is None else args.progress,
        shm=args.shm,
        max_frame_bytes=args.max_frame_bytes,
        compressed=compressed,
    )
