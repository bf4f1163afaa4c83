"""Frame sources for ``zenoh-perception replay``: what a camera would publish, read from disk.

Pure: no Zenoh, no logging. Every source yields :class:`SourceFrame` tuples ``(payload,
attachment, stamp_ns)``, exactly what goes on the wire plus the recording-clock time that paces
it:

- :class:`BagSource` (rosbag2 folder, ``.mcap`` or ``.db3`` file, read with rosbags): the
  ORIGINAL sensor_msgs/msg/Image CDR bytes of one topic, unchanged (header stamp included), no
  attachment — what zenoh-bridge-ros2dds publishes. ``stamp_ns`` is the bag's receive time.
- :class:`VideoSource` (anything ``cv2.VideoCapture`` opens) and :class:`ImageSequenceSource`
  (a folder of images sorted by name, or one image): raw BGRA pixels with the msgpack attachment
  of ``schemas/frame-attachment.schema.json`` (``stamp_ns`` = ``epoch_ns`` + the frame's offset
  in the recording, ``seq`` counting from ``seq_start``, ``frame_id``).

:func:`open_source` picks the source for a path.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Generator, Sequence
from pathlib import Path
from typing import Final, NamedTuple, Protocol

import cv2
import numpy as np
import numpy.typing as npt
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader, ReaderError

from zenoh_perception.camera.defaults import DEFAULT_FRAME_ID, DEFAULT_RATE_HZ, DEFAULT_TOPIC
from zenoh_perception.errors import PerceptionError, SettingsError
from zenoh_perception.files import check_nesting, read_text_file
from zenoh_perception.settings import FRAME_LIMITS_HINT
from zenoh_perception.wire.frames import MAX_DIMENSION, RawFrameMeta
from zenoh_perception.wire.image_header import image_header_size
from zenoh_perception.wire.messages import IMAGE_TYPE

BAG_SUFFIXES: Final = frozenset({".mcap", ".db3"})
#: Files of an image folder that are read (case-insensitive); everything else is ignored.
IMAGE_SUFFIXES: Final = frozenset(
    {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pnm"}
)


class ReplayError(PerceptionError):
    """A replay source cannot be opened or read, or the replay cannot start."""


class SourceFrame(NamedTuple):
    """One frame as published: payload, attachment (None for CDR), recording-clock time."""

    payload: bytes
    attachment: bytes | None
    stamp_ns: int


#: One pass over a source (a generator, so a partly read pass can be closed early).
Frames = Generator[SourceFrame, None, None]


class FrameSource(Protocol):
    """A finite, re-readable sequence of frames (each :meth:`frames` call is one pass)."""

    @property
    def kind(self) -> str:
        """Short name of the source type, for logs."""

    @property
    def count(self) -> int | None:
        """Frames per pass when known (for the progress bar)."""

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        """One pass over the frames. Raw sources stamp ``epoch_ns`` + offset and number from
        ``seq_start``; bags ignore both (their CDR carries its own header)."""


def _period_ns(rate_hz: float) -> int:
    if not math.isfinite(rate_hz) or rate_hz <= 0:
        msg = f"frame rate must be a positive number, not {rate_hz!r}"
        raise ReplayError(msg)
    return max(1, round(1e9 / rate_hz))


def _raw_frame(image: npt.ArrayLike, *, stamp_ns: int, seq: int, frame_id: str) -> SourceFrame:
    """One decoded image (grey, BGR or BGRA) as a ZED camera sends it: BGRA payload and
    msgpack attachment."""
    pixels = np.asarray(image, dtype=np.uint8)
    if pixels.ndim == 2:
        bgra = cv2.cvtColor(pixels, cv2.COLOR_GRAY2BGRA)
    elif pixels.shape[2] == 4:
        bgra = pixels
    else:
        bgra = cv2.cvtColor(pixels, cv2.COLOR_BGR2BGRA)
    height, width = int(bgra.shape[0]), int(bgra.shape[1])
    meta = RawFrameMeta(
        width=width,
        height=height,
        encoding="bgra8",
        stamp_ns=stamp_ns,
        frame_id=frame_id,
        seq=seq,
    )
    return SourceFrame(np.ascontiguousarray(bgra).tobytes(), meta.to_msgpack(), stamp_ns)


# -- rosbag2 ---------------------------------------------------------------------------------


#: What rosbags raises on a corrupt bag: a bit flipped in a record's length makes it read (and
#: try to allocate) that many bytes (MemoryError), overflow a seek (OverflowError) or unpack
#: a record cut short (struct.error).
_BAG_ERRORS: Final = (
    ReaderError,
    OSError,
    ValueError,
    KeyError,
    MemoryError,
    OverflowError,
    struct.error,
)


def _open_reader(path: Path) -> Reader:
    metadata = path / "metadata.yaml" if path.is_dir() else None
    if metadata is not None and metadata.is_file():
        # rosbags' YAML parser recurses per level: a deeply nested file is refused first
        try:
            check_nesting(read_text_file(metadata, "rosbag2 metadata"), f"rosbag2 {metadata}")
        except SettingsError as err:
            raise ReplayError(str(err)) from err
    try:
        reader = Reader(path)
        reader.open()
    except _BAG_ERRORS as err:
        msg = f"cannot read rosbag2 {str(path)!r}: {err}"
        raise ReplayError(msg) from err
    return reader


def choose_image_topic(topics: dict[str, str], requested: str | None) -> str:
    """The topic to replay among ``topics`` (name -> message type).

    ``requested`` (with or without its leading slash) must exist and be a sensor_msgs/msg/Image
    topic; without it: the only Image topic, else :data:`DEFAULT_TOPIC` when present.

    Raises:
        ReplayError: no such topic, not an Image topic, or no unambiguous choice.

    """
    images = sorted(name for name, msgtype in topics.items() if msgtype == IMAGE_TYPE)
    if requested is not None:
        candidates = [requested] if requested.startswith("/") else [requested, f"/{requested}"]
        for name in candidates:
            if name in topics:
                if topics[name] != IMAGE_TYPE:
                    msg = f"topic {name!r} is {topics[name]}, not {IMAGE_TYPE}"
                    raise ReplayError(msg)
                return name
        msg = f"no topic {requested!r} in the bag (Image topics: {', '.join(images) or 'none'})"
        raise ReplayError(msg)
    if len(images) == 1:
        return images[0]
    if DEFAULT_TOPIC in images:
        return DEFAULT_TOPIC
    if not images:
        msg = f"the bag has no {IMAGE_TYPE} topic (topics: {', '.join(sorted(topics)) or 'none'})"
        raise ReplayError(msg)
    msg = f"several {IMAGE_TYPE} topics ({', '.join(images)}); choose one with --topic"
    raise ReplayError(msg)


class BagSource:
    """The sensor_msgs/msg/Image messages of one topic of a rosbag2, bytes unchanged."""

    kind = "rosbag2"

    def __init__(self, path: Path, topic: str | None = None) -> None:
        """Open the bag once to choose the topic and count its messages.

        Raises:
            ReplayError: unreadable bag, no suitable topic, or a non-CDR serialization.

        """
        self.path = path
        reader = _open_reader(path)
        try:
            topics = {name: info.msgtype or "" for name, info in reader.topics.items()}
            self.topic = choose_image_topic(topics, topic)
            connections = reader.topics[self.topic].connections
            self._count = sum(conn.msgcount for conn in connections)
            for conn in connections:
                fmt = getattr(conn.ext, "serialization_format", "cdr")
                if fmt != "cdr":
                    msg = f"topic {self.topic!r} is serialised as {fmt!r}, not cdr"
                    raise ReplayError(msg)
        finally:
            reader.close()

    @property
    def count(self) -> int | None:
        return self._count

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        del epoch_ns, seq_start  # the CDR header carries the recorded stamp and frame_id
        reader = _open_reader(self.path)
        try:
            connections: Sequence[Connection] = reader.topics[self.topic].connections
            try:
                for _conn, timestamp, data in reader.messages(connections=connections):
                    yield SourceFrame(bytes(data), None, int(timestamp))
            except _BAG_ERRORS as err:
                msg = f"cannot read rosbag2 {str(self.path)!r}: {err}"
                raise ReplayError(msg) from err
        finally:
            reader.close()


# -- video -----------------------------------------------------------------------------------


class VideoSource:
    """Frames of a video file decoded by OpenCV, sent as raw BGRA."""

    kind = "video"

    def __init__(self, path: Path, *, frame_id: str = DEFAULT_FRAME_ID) -> None:
        """Open the video once to read its frame rate and length.

        Raises:
            ReplayError: OpenCV cannot open the file.

        """
        self.path = path
        self.frame_id = frame_id
        capture = self._open()
        try:
            fps = float(capture.get(cv2.CAP_PROP_FPS))
            frames = float(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        finally:
            capture.release()
        #: The frame rate the file states, or :data:`DEFAULT_RATE_HZ` when it states none.
        self.fps = fps if math.isfinite(fps) and 0 < fps <= 1000 else DEFAULT_RATE_HZ
        self._count = int(frames) if math.isfinite(frames) and frames > 0 else None

    def _open(self) -> cv2.VideoCapture:
        if not self.path.is_file():
            msg = f"no such video file: {str(self.path)!r}"
            raise ReplayError(msg)
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            capture.release()
            msg = f"OpenCV cannot open {str(self.path)!r} as a video"
            raise ReplayError(msg)
        return capture

    @property
    def count(self) -> int | None:
        return self._count

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        period = _period_ns(self.fps)
        capture = self._open()
        try:
            index = 0
            while True:
                ok, image = capture.read()
                if not ok or image is None:
                    return
                yield _raw_frame(
                    image,
                    stamp_ns=epoch_ns + index * period,
                    seq=seq_start + index,
                    frame_id=self.frame_id,
                )
                index += 1
        finally:
            capture.release()


# -- images ----------------------------------------------------------------------------------


def list_images(folder: Path) -> list[Path]:
    """The image files directly in ``folder``, sorted by name (other files are ignored)."""
    try:
        entries = list(folder.iterdir())
    except OSError as err:
        msg = f"cannot list {str(folder)!r}: {err}"
        raise ReplayError(msg) from err
    files = [p for p in entries if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]
    return sorted(files, key=lambda p: p.name)


def skipped_files(folder: Path) -> tuple[Path, ...]:
    """The files directly in ``folder`` that :func:`list_images` leaves out, sorted by name."""
    try:
        entries = list(folder.iterdir())
    except OSError:
        return ()
    others = [p for p in entries if p.suffix.lower() not in IMAGE_SUFFIXES and p.is_file()]
    return tuple(sorted(others, key=lambda p: p.name))


class ImageSequenceSource:
    """Still images sent one after the other as raw BGRA, ``rate_hz`` apart on the stamp clock."""

    kind = "images"

    def __init__(
        self,
        files: Sequence[Path],
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        frame_id: str = DEFAULT_FRAME_ID,
        max_frame_bytes: int | None = None,
    ) -> None:
        if not files:
            msg = "no images to replay"
            raise ReplayError(msg)
        self.files = tuple(files)
        #: Files of the folder that are no image (videos, notes), left out of the sequence.
        self.skipped: tuple[Path, ...] = ()
        self.frame_id = frame_id
        self.rate_hz = rate_hz
        self.max_frame_bytes = max_frame_bytes
        self._period = _period_ns(rate_hz)

    @classmethod
    def from_folder(
        cls,
        folder: Path,
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        frame_id: str = DEFAULT_FRAME_ID,
        max_frame_bytes: int | None = None,
    ) -> ImageSequenceSource:
        files = list_images(folder)
        if not files:
            msg = (
                f"{str(folder)!r} holds neither a rosbag2 (metadata.yaml) nor images "
                f"({', '.join(sorted(IMAGE_SUFFIXES))})"
            )
            raise ReplayError(msg)
        source = cls(files, rate_hz=rate_hz, frame_id=frame_id, max_frame_bytes=max_frame_bytes)
        source.skipped = skipped_files(folder)
        return source

    @property
    def count(self) -> int | None:
        return len(self.files)

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        for index, path in enumerate(self.files):
            image = self._read(path, index + 1)
            if image is None:
                msg = f"OpenCV cannot read the image {str(path)!r}"
                raise ReplayError(msg)
            yield _raw_frame(
                image,
                stamp_ns=epoch_ns + index * self._period,
                seq=seq_start + index,
                frame_id=self.frame_id,
            )

    def _read(self, path: Path, number: int) -> npt.NDArray[np.uint8] | None:
        """The image at ``path`` (frame ``number``), decoded only after the size its header
        declares is checked (a small file may declare a huge image).

        Raises:
            ReplayError: unreadable, or declaring a frame the service would refuse: larger
                than MAX_DIMENSION a side or, as BGRA, than ``max_frame_bytes``.

        """
        try:
            data = path.read_bytes()
        except OSError as err:
            msg = f"cannot read the image {str(path)!r}: {err.strerror or err}"
            raise ReplayError(msg) from err
        size = image_header_size(data)
        if size is not None:
            width, height = size
            if width > MAX_DIMENSION or height > MAX_DIMENSION:
                msg = (
                    f"frame {number} of the images, {str(path)!r}, declares {width}x{height} "
                    f"pixels, over {MAX_DIMENSION} a side: not decoded"
                )
                raise ReplayError(msg)
            limit = self.max_frame_bytes
            if limit is not None and width * height * 4 > limit:  # sent as BGRA
                msg = (
                    f"frame {number} of the images is {width * height * 4} bytes, over "
                    f"max_frame_bytes = {limit}: the service would refuse it; "
                    f"{FRAME_LIMITS_HINT} ({str(path)!r} declares {width}x{height} pixels: "
                    "not decoded)"
                )
                raise ReplayError(msg)
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        return None if image is None else np.asarray(image, dtype=np.uint8)


# -- choosing --------------------------------------------------------------------------------


def open_source(
    path: Path,
    *,
    topic: str | None = None,
    image_rate_hz: float = DEFAULT_RATE_HZ,
    frame_id: str = DEFAULT_FRAME_ID,
    max_frame_bytes: int | None = None,
) -> FrameSource:
    """The source for ``path``.

    A folder with ``metadata.yaml``, or a ``.mcap`` / ``.db3`` file, is a rosbag2; another
    folder is a folder of images; an image file is a one-image sequence; any other file is
    opened as a video.

    Raises:
        ReplayError: the path does not exist or its content cannot be replayed.

    """
    if not path.exists():
        msg = f"no such file or folder: {str(path)!r}"
        raise ReplayError(msg)
    suffix = path.suffix.lower()
    if (path.is_dir() and (path / "metadata.yaml").is_file()) or (
        path.is_file() and suffix in BAG_SUFFIXES
    ):
        return BagSource(path, topic)
    if topic is not None:
        msg = f"a topic applies to rosbag2 sources only, and {str(path)!r} is not a bag"
        raise ReplayError(msg)
    if path.is_dir():
        return ImageSequenceSource.from_folder(
            path, rate_hz=image_rate_hz, frame_id=frame_id, max_frame_bytes=max_frame_bytes
        )
    if suffix in IMAGE_SUFFIXES:
        return ImageSequenceSource(
            [path], rate_hz=image_rate_hz, frame_id=frame_id, max_frame_bytes=max_frame_bytes
        )
    return VideoSource(path, frame_id=frame_id)
