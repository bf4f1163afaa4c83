"""``zenoh-perception view``: watch the service's annotated debug image.

Subscribes to ``debug_image_key`` (sensor_msgs/CompressedImage CDR; the service draws it only
while someone subscribes, so this is what starts it). Where a window can be opened (a display,
and an OpenCV with a GUI: not ``opencv-python-headless``) it shows the images as they come;
``--save PATH`` also writes the latest JPEG to PATH every ``--every`` seconds (replaced
atomically, so a reader never sees half a file), and without a display that is all it does.
Zenoh's callback only keeps the newest payload; decoding and writing happen on the main thread.
A key holding ``{stream}`` (``run``'s own ``debug_image_key`` beside several cameras) is one
stream's with ``--stream NAME``, every stream's without. Nothing within ``--timeout``: exit 1,
one line naming the key.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Final, TextIO

import cv2
import numpy as np
import zenoh

from zenoh_perception.errors import CompressedImageCdrError, PerceptionError
from zenoh_perception.service.zenoh_args import open_zenoh
from zenoh_perception.wire.compressed import compressed_image_data
from zenoh_perception.wire.image_header import image_header_size
from zenoh_perception.wire.stream_keys import STREAM, every_output_key, output_key

WINDOW: Final = "zenoh-perception debug image"
_POLL_S: Final = 0.03


class ViewError(PerceptionError):
    """``view`` cannot show or save the debug image (no display, a path it cannot write)."""


def display_available() -> bool:
    """Whether a window can be opened: a display to open it on, and OpenCV built with a GUI
    (``opencv-python-headless`` raises on any window call)."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return False
    try:
        cv2.namedWindow(WINDOW, cv2.WINDOW_NORMAL)
    except cv2.error:
        return False
    return True


class _Latest:
    """The newest payload received (Zenoh's callback only swaps a reference)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._payload: bytes | None = None
        self._number = 0

    def on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        with self._lock:
            self._payload = payload
            self._number += 1

    def take(self) -> tuple[int, bytes | None]:
        with self._lock:
            return self._number, self._payload


@dataclass(frozen=True, slots=True)
class ViewOptions:
    key: str
    save: Path | None
    every_s: float
    count: int  # saves before exiting; 0 = no limit
    timeout_s: float | None


def view_key(template: str, stream: str | None) -> str:
    """The key expression to watch: ``template`` (a debug image key, maybe holding
    ``{stream}``) for the stream named ``stream``, or for every stream when None.

    Raises:
        ViewError: a stream named while ``template`` holds no ``{stream}``.

    """
    if stream is None:
        return every_output_key(template)
    if STREAM not in template:
        msg = (
            f"--stream {stream!r}: the debug image key {template!r} holds no {STREAM!r}; give "
            f"the service's own, e.g. --debug-image-key 'rover/{STREAM}/perception/debug/image/"
            "compressed' (or --settings FILE)"
        )
        raise ViewError(msg)
    return output_key(template, stream)


def save_atomically(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it, then rename it in place.

    Raises:
        ViewError: the file cannot be written.

    """
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_bytes(data)
        tmp.replace(path)
    except OSError as err:
        msg = f"cannot write --save {path}: {err.strerror or err}"
        raise ViewError(msg) from err


def main(
    conf: zenoh.Config,
    options: ViewOptions,
    stop: threading.Event,
    *,
    out: TextIO = sys.stdout,
) -> int:
    """Show and/or save the debug image until stopped, ``--count`` saves or ``--timeout``;
    0, or 1 (with a line on stderr naming the key) when no image came within ``--timeout``.

    Raises:
        ViewError: no display and no ``--save``, or the save path cannot be written.
        SessionError: the Zenoh session cannot be opened.

    """
    window = display_available()
    if not window and options.save is None:
        msg = (
            "no display to show the debug image on (DISPLAY unset, or OpenCV without a GUI): "
            "use --save PATH to write it to a file instead"
        )
        raise ViewError(msg)
    latest = _Latest()
    deadline = None if options.timeout_s is None else time.monotonic() + options.timeout_s
    reader = _Reader(options.key, out)
    shown = saved = saves = 0
    next_save = time.monotonic()
    try:
        with open_zenoh(conf) as session, session.declare_subscriber(options.key, latest.on_sample):
            while not stop.is_set():
                if deadline is not None and time.monotonic() >= deadline:
                    break
                number, payload = latest.take()
                if window:
                    if number != shown and payload is not None:
                        shown = number
                        _show(reader.data(number, payload))
                    if cv2.waitKey(1) & 0xFF == ord("q"):
                        break
                now = time.monotonic()
                due = options.save is not None and now >= next_save
                if due and payload is not None and number != saved:
                    saved, next_save = number, now + options.every_s
                    data = reader.data(number, payload)
                    if data is not None and options.save is not None:
                        save_atomically(options.save, data)
                        saves += 1
                        size = image_header_size(data)
                        dims = "?x?" if size is None else f"{size[0]}x{size[1]}"
                        print(f"saved {options.save} {dims} image={number}", file=out, flush=True)
                        if options.count and saves >= options.count:
                            break
                stop.wait(_POLL_S)
    finally:
        if window:
            cv2.destroyAllWindows()
    if options.timeout_s is not None and latest.take()[0] == 0 and not stop.is_set():
        print(
            f"view: no debug image arrived on {options.key!r} within {options.timeout_s:g} s: "
            "is a service running with debug_image on, and is this its debug_image_key "
            f"(several cameras: --stream NAME with the {STREAM!r} key run was given)?",
            file=sys.stderr,
        )
        return 1
    return 0


def _show(data: bytes | None) -> None:
    if data is None:
        return
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is not None:
        cv2.imshow(WINDOW, image)


class _Reader:
    """The JPEG of the newest payload, read once per payload; a payload that is not a
    CompressedImage is skipped, with one line the first time."""

    def __init__(self, key: str, out: TextIO) -> None:
        self._key = key
        self._out = out
        self._number = -1
        self._data: bytes | None = None
        self.bad = 0

    def data(self, number: int, payload: bytes) -> bytes | None:
        if number != self._number:
            self._number = number
            try:
                _fmt, self._data = compressed_image_data(payload)
            except CompressedImageCdrError as err:
                self._data = None
                self.bad += 1
                if self.bad == 1:
                    print(
                        f"view: skipped what is not a CompressedImage on {self._key}: {err}",
                        file=self._out,
                        flush=True,
                    )
        return self._data
