"""Camera frame decoding: raw pixels with a msgpack attachment, or sensor_msgs/Image CDR.

Both decoders return a :class:`Frame` whose ``pixels`` is a *view* into the payload (no pixel
copy): rows may be padded (``step`` larger than ``width * channels``) and are described by numpy
strides rather than copied away. Every size is checked against the bytes actually present before
any view is built, so a hostile header can never make the decoder allocate or read past the
payload.

Limits: a payload of more than the service's ``max_frame_bytes`` is refused before it is copied
(:func:`check_payload_size`), a frame of more than ``max_pixels`` pixels before it is viewed, and
a stamp must lie in [0, :data:`MAX_STAMP_NS`] whether it comes from a raw frame's attachment or
a CDR header (ROS 2 refuses negative times: rclcpp::Time throws on them).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, cast

import cv2
import msgpack
import numpy as np
import numpy.typing as npt

from zenoh_perception.errors import (
    AttachmentError,
    DimensionError,
    ImageCdrError,
    PayloadTooLargeError,
    SizeMismatchError,
    StampError,
    TooManyPixelsError,
    UnsupportedEncodingError,
)
from zenoh_perception.tags import geometry
from zenoh_perception.wire.messages import (
    IMAGE_TYPE,
    TYPESTORE,
    deserialize,
    header,
    stamp_ns_of,
    unpack_msgpack_map,
)

Pixels = npt.NDArray[np.uint8]

#: Largest accepted width or height. Bigger values are treated as corrupt headers.
MAX_DIMENSION: Final = geometry.MAX_DIMENSION
#: Largest pixel count: what MAX_DIMENSION allows; the service's max_frame_pixels is lower.
MAX_PIXELS: Final = MAX_DIMENSION * MAX_DIMENSION
#: Largest accepted stamp, nanoseconds since the epoch (a signed 64-bit count).
MAX_STAMP_NS: Final = 2**63 - 1
#: Largest accepted attachment; real ones are well under 200 bytes.
MAX_ATTACHMENT_BYTES: Final = 4096
#: Largest accepted frame_id length, in characters (raw and CDR alike).
MAX_FRAME_ID_CHARS: Final = 256
#: Largest accepted ``seq`` of a raw frame's attachment: a 32-bit frame counter (ROS 1's
#: Header.seq), so no hostile counter makes a consumer count 2**64 records missing.
MAX_SEQ: Final = 2**32 - 1
#: A CDR stamp's nanoseconds are below one second (builtin_interfaces/Time).
NANOSEC_PER_SEC: Final = 1_000_000_000


@dataclass(frozen=True, slots=True)
class PixelEncoding:
    """How one ROS image encoding maps to channels and to an OpenCV grey conversion."""

    name: str
    channels: int
    to_gray: int | None  # cv2.COLOR_* code, None when already grey
    to_bgr: int | None  # cv2.COLOR_* code, None when already BGR


ENCODINGS: Final[Mapping[str, PixelEncoding]] = {
    "bgra8": PixelEncoding("bgra8", 4, cv2.COLOR_BGRA2GRAY, cv2.COLOR_BGRA2BGR),
    "bgr8": PixelEncoding("bgr8", 3, cv2.COLOR_BGR2GRAY, None),
    "rgba8": PixelEncoding("rgba8", 4, cv2.COLOR_RGBA2GRAY, cv2.COLOR_RGBA2BGR),
    "rgb8": PixelEncoding("rgb8", 3, cv2.COLOR_RGB2GRAY, cv2.COLOR_RGB2BGR),
    "mono8": PixelEncoding("mono8", 1, None, cv2.COLOR_GRAY2BGR),
}

DEFAULT_ENCODING: Final = "bgra8"


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded camera frame.

    ``pixels`` has shape (height, width, channels), or (height, width) for mono8, and may be a
    read-only, row-strided view into the received payload.
    """

    pixels: Pixels
    encoding: PixelEncoding
    stamp_ns: int | None
    frame_id: str
    seq: int | None

    @property
    def width(self) -> int:
        return int(self.pixels.shape[1])

    @property
    def height(self) -> int:
        return int(self.pixels.shape[0])


@dataclass(frozen=True, slots=True)
class RawFrameMeta:
    """The attachment of a raw frame (see ``schemas/frame-attachment.schema.json``)."""

    width: int
    height: int
    encoding: str = DEFAULT_ENCODING
    step: int | None = None
    stamp_ns: int | None = None
    frame_id: str = ""
    seq: int | None = None

    def to_msgpack(self) -> bytes:
        """Encode as the attachment a camera sends (keys with ``None`` values are left out)."""
        fields: dict[str, object] = {
            "width": self.width,
            "height": self.height,
            "encoding": self.encoding,
        }
        for key in ("step", "stamp_ns", "seq"):
            value = getattr(self, key)
            if value is not None:
                fields[key] = value
        if self.frame_id:
            fields["frame_id"] = self.frame_id
        packed: bytes = msgpack.packb(fields)
        return packed


def _int_field(fields: Mapping[Any, Any], key: str, *, required: bool) -> int | None:
    value = fields.get(key)
    if value is None:
        if required:
            msg = f"attachment lacks {key!r}"
            raise AttachmentError(msg)
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        msg = f"attachment {key!r} is {type(value).__name__}, not int"
        raise AttachmentError(msg)
    return value


def decode_attachment(data: bytes | memoryview | None) -> RawFrameMeta:
    """Parse and type-check a raw frame's msgpack attachment.

    Raises:
        AttachmentError: missing, oversized, not msgpack, not a map, or wrongly typed fields.

    """
    if data is None or len(data) == 0:
        msg = "raw frame without attachment"
        raise AttachmentError(msg)
    if len(data) > MAX_ATTACHMENT_BYTES:
        msg = f"attachment of {len(data)} bytes exceeds {MAX_ATTACHMENT_BYTES}"
        raise AttachmentError(msg)
    fields = unpack_msgpack_map(data, AttachmentError, "attachment")
    encoding = fields.get("encoding", DEFAULT_ENCODING)
    if not isinstance(encoding, str):
        msg = "attachment 'encoding' is not a string"
        raise AttachmentError(msg)
    frame_id = fields.get("frame_id", "")
    if not isinstance(frame_id, str) or len(frame_id) > MAX_FRAME_ID_CHARS:
        msg = "attachment 'frame_id' is not a string of at most 256 characters"
        raise AttachmentError(msg)
    width = _int_field(fields, "width", required=True)
    height = _int_field(fields, "height", required=True)
    stamp_ns = _int_field(fields, "stamp_ns", required=False)
    if stamp_ns is not None:
        check_stamp(stamp_ns)
    if width is None or height is None:  # pragma: no cover - required=True guarantees ints
        msg = "attachment lacks width or height"
        raise AttachmentError(msg)
    seq = _int_field(fields, "seq", required=False)
    if seq is not None and not 0 <= seq <= MAX_SEQ:
        msg = f"attachment 'seq' {seq} is outside [0, {MAX_SEQ}]"
        raise AttachmentError(msg)
    return RawFrameMeta(
        width=width,
        height=height,
        encoding=encoding,
        step=_int_field(fields, "step", required=False),
        stamp_ns=stamp_ns,
        frame_id=frame_id,
        seq=seq,
    )


def check_stamp(stamp_ns: int) -> int:
    """``stamp_ns`` itself when it lies in [0, MAX_STAMP_NS].

    Raises:
        StampError: a negative stamp (before the epoch) or one past a signed 64-bit count.

    """
    if not 0 <= stamp_ns <= MAX_STAMP_NS:
        msg = f"stamp {stamp_ns} ns is outside [0, {MAX_STAMP_NS}]"
        raise StampError(msg)
    return stamp_ns


def check_payload_size(size: int, max_bytes: int) -> None:
    """Refuse a frame payload of ``size`` bytes when it exceeds ``max_bytes``.

    Raises:
        PayloadTooLargeError: ``size > max_bytes``.

    """
    if size > max_bytes:
        msg = f"frame payload of {size} bytes exceeds max_frame_bytes = {max_bytes}"
        raise PayloadTooLargeError(msg)


def _lookup_encoding(name: str) -> PixelEncoding:
    try:
        return ENCODINGS[name.lower()]
    except KeyError as err:
        msg = f"unsupported encoding {name[:32]!r} (supported: {', '.join(ENCODINGS)})"
        raise UnsupportedEncodingError(msg) from err


def pixel_view(
    buffer: Pixels,
    width: int,
    height: int,
    step: int | None,
    encoding: PixelEncoding,
    *,
    max_pixels: int = MAX_PIXELS,
) -> Pixels:
    """Build a (height, width[, channels]) view over ``buffer`` honouring a row ``step``.

    ``buffer`` must be a 1-D uint8 array holding exactly ``step * height`` bytes.

    Raises:
        DimensionError: non-positive or absurd width/height, or a step shorter than a row.
        SizeMismatchError: ``buffer`` does not hold exactly ``step * height`` bytes.
        TooManyPixelsError: a consistent frame of more than ``max_pixels`` pixels.

    """
    if not (0 < width <= MAX_DIMENSION and 0 < height <= MAX_DIMENSION):
        msg = f"dimensions {width}x{height} outside 1..{MAX_DIMENSION}"
        raise DimensionError(msg)
    row_bytes = width * encoding.channels
    if step is None:
        step = row_bytes
    if step < row_bytes or step > row_bytes + MAX_DIMENSION:
        msg = f"step {step} does not fit rows of {row_bytes} bytes"
        raise DimensionError(msg)
    if buffer.size != step * height:
        msg = f"{buffer.size} pixel bytes for {width}x{height} {encoding.name} step {step}"
        raise SizeMismatchError(msg)
    if width * height > max_pixels:
        msg = f"{width}x{height} = {width * height} pixels exceeds max_frame_pixels = {max_pixels}"
        raise TooManyPixelsError(msg)
    if encoding.channels == 1:
        shape: tuple[int, ...] = (height, width)
        strides: tuple[int, ...] = (step, 1)
    else:
        shape = (height, width, encoding.channels)
        strides = (step, encoding.channels, 1)
    view: Pixels = np.lib.stride_tricks.as_strided(
        buffer, shape=shape, strides=strides, writeable=False
    )
    return view


def decode_raw_frame(
    payload: bytes | memoryview,
    attachment: bytes | memoryview | None,
    *,
    max_pixels: int = MAX_PIXELS,
) -> Frame:
    """Decode raw pixels described by a msgpack attachment (zero-copy view of ``payload``).

    Raises:
        FrameDecodeError: a subclass naming what is wrong.

    """
    meta = decode_attachment(attachment)
    encoding = _lookup_encoding(meta.encoding)
    buffer = np.frombuffer(payload, dtype=np.uint8)
    pixels = pixel_view(buffer, meta.width, meta.height, meta.step, encoding, max_pixels=max_pixels)
    return Frame(pixels, encoding, meta.stamp_ns, meta.frame_id, meta.seq)


def decode_image_cdr(payload: bytes | memoryview, *, max_pixels: int = MAX_PIXELS) -> Frame:
    """Decode a ROS 2 sensor_msgs/msg/Image CDR sample (with its 4-byte encapsulation header).

    ``data`` is a zero-copy view of ``payload`` when ``payload`` is a memoryview or bytes.

    Raises:
        FrameDecodeError: a subclass naming what is wrong.

    """
    msg = deserialize(payload, IMAGE_TYPE, ImageCdrError)
    encoding = _lookup_encoding(str(msg.encoding))
    data: Pixels = msg.data
    if data.ndim != 1 or data.dtype != np.uint8:  # pragma: no cover - rosbags always gives uint8[]
        text = "Image.data is not a uint8 sequence"
        raise ImageCdrError(text)
    nanosec = int(msg.header.stamp.nanosec)
    if nanosec >= NANOSEC_PER_SEC:
        text = f"stamp nanosec {nanosec} is not below {NANOSEC_PER_SEC}"
        raise StampError(text)
    stamp_ns = check_stamp(stamp_ns_of(msg.header))
    frame_id = str(msg.header.frame_id)
    if len(frame_id) > MAX_FRAME_ID_CHARS:
        text = f"header frame_id of {len(frame_id)} characters, over {MAX_FRAME_ID_CHARS}"
        raise ImageCdrError(text)
    pixels = pixel_view(
        data, int(msg.width), int(msg.height), int(msg.step), encoding, max_pixels=max_pixels
    )
    return Frame(pixels, encoding, stamp_ns, frame_id, None)


def encode_image_cdr(
    pixels: Pixels, encoding: str, *, stamp_ns: int = 0, frame_id: str = "", step: int | None = None
) -> memoryview:
    """Serialise pixels as sensor_msgs/msg/Image CDR, as a ROS 2 camera driver would.

    ``step`` larger than a row pads each row with zero bytes (like drivers that align rows).
    """
    enc = _lookup_encoding(encoding)
    height, width = int(pixels.shape[0]), int(pixels.shape[1])
    row_bytes = width * enc.channels
    step = row_bytes if step is None else step
    if step < row_bytes:
        msg = f"step {step} shorter than a row of {row_bytes} bytes"
        raise DimensionError(msg)
    rows = np.ascontiguousarray(pixels, dtype=np.uint8).reshape(height, row_bytes)
    if step == row_bytes:
        data = rows.reshape(-1)
    else:
        padded = np.zeros((height, step), dtype=np.uint8)
        padded[:, :row_bytes] = rows
        data = padded.reshape(-1)
    image = TYPESTORE.types[IMAGE_TYPE](
        header=header(stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=enc.name,
        is_bigendian=0,
        step=step,
        data=data,
    )
    raw: memoryview = TYPESTORE.serialize_cdr(image, IMAGE_TYPE)
    return raw


def to_gray(frame: Frame, out: Pixels | None = None) -> Pixels:
    """Convert straight from the frame's encoding to one grey channel (no intermediate BGR),
    into ``out`` (an (height, width) uint8 array) when given, else into a new array (a grey
    frame is then returned as it is)."""
    if frame.encoding.to_gray is None:
        if out is None:
            return frame.pixels
        np.copyto(out, frame.pixels.reshape(out.shape))
        return out
    return cast(Pixels, cv2.cvtColor(frame.pixels, frame.encoding.to_gray, dst=out))


def to_bgr(frame: Frame) -> Pixels:
    """Convert the frame to a new BGR image (used for the debug image only)."""
    if frame.encoding.to_bgr is None:
        return np.array(frame.pixels, copy=True)
    return cast(Pixels, cv2.cvtColor(frame.pixels, frame.encoding.to_bgr))
