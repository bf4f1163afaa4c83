"""Compressed camera frames: sensor_msgs/msg/CompressedImage CDR (JPEG or PNG) in and out.

What image_transport's ``compressed`` plugin publishes on ``<camera>/compressed`` (and
zenoh-bridge-ros2dds forwards unchanged): a header, a ``format`` string and the encoded bytes.
Its ``format`` strings are ``"<original encoding>; <codec> compressed <encoded as>"``
(``"bgr8; jpeg compressed bgr8"``, ``"rgb8; jpeg compressed bgr8"``,
``"mono8; png compressed mono8"``); older publishers and cv_bridge write just ``"jpeg"`` or
``"png"``. Anything else (``compressedDepth``, TIFF, ...) is refused.

Before OpenCV decodes anything the size the image declares in its header is read
(:func:`~zenoh_perception.wire.image_header.image_header_size`) and held to ``max_pixels``:
a PNG of a few bytes can declare gigabytes. A frame must also end as its codec ends (JPEG's EOI
marker, PNG's IEND chunk): a cut frame is refused as truncated rather than decoded half grey.

Rejection reasons (each a :class:`~zenoh_perception.errors.FrameDecodeError`):
``bad_compressed_cdr`` (not CompressedImage CDR), ``unsupported_image_format`` (a format other
than JPEG or PNG), ``truncated_image`` (empty, or no end of image), ``corrupt_image`` (bytes not
of the format said, no readable size, undecodable, or decoded to another size than declared),
``bad_dimensions`` / ``too_many_pixels`` (the declared size), ``bad_stamp``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal, cast

import cv2
import numpy as np

from zenoh_perception.errors import (
    CompressedImageCdrError,
    CorruptImageError,
    DimensionError,
    ImageFormatError,
    TooManyPixelsError,
    TruncatedImageError,
)
from zenoh_perception.wire.frames import (
    ENCODINGS,
    MAX_DIMENSION,
    MAX_FRAME_ID_CHARS,
    MAX_PIXELS,
    Frame,
    Pixels,
    check_stamp,
    to_bgr,
)
from zenoh_perception.wire.image_header import JPEG_SOI, PNG_SIGNATURE, image_header_size
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.messages import (
    COMPRESSED_IMAGE_TYPE,
    TYPESTORE,
    deserialize,
    header,
    stamp_ns_of,
)
from zenoh_perception.wire.ros_topics import input_role, ros_topic

#: The input: the ROS topic of ``compressed_input_key``'s default and its type.
COMPRESSED_INPUT_TOPIC: Final = ros_topic(input_role(InputKind.COMPRESSED))

Codec = Literal["jpeg", "png"]
CODECS: Final[tuple[Codec, ...]] = ("jpeg", "png")
_CODEC_NAMES: Final[dict[str, Codec]] = {"jpeg": "jpeg", "jpg": "jpeg", "png": "png"}
_MAGIC: Final[dict[Codec, bytes]] = {"jpeg": JPEG_SOI + b"\xff", "png": PNG_SIGNATURE}
#: What the last bytes of a whole image are: JPEG's EOI marker, PNG's IEND chunk (empty, with
#: its fixed CRC).
_END: Final[dict[Codec, bytes]] = {
    "jpeg": b"\xff\xd9",
    "png": b"\x00\x00\x00\x00IEND\xae\x42\x60\x82",
}
#: Longest ``format`` string read; image_transport's are under 40 characters.
MAX_FORMAT_CHARS: Final = 128


@dataclass(frozen=True, slots=True)
class ImageFormat:
    """A parsed ``format``: the codec and, when stated, the camera's encoding before it."""

    codec: Codec | None  # None: not stated (an empty format), read from the bytes
    original: str | None

    @property
    def grey(self) -> bool:
        return self.original == "mono8"


def parse_format(text: str) -> ImageFormat:
    """The codec (and original encoding) a CompressedImage ``format`` names.

    Raises:
        ImageFormatError: a codec other than JPEG or PNG, or an over-long string.

    """
    if len(text) > MAX_FORMAT_CHARS:
        msg = f"format of {len(text)} characters (at most {MAX_FORMAT_CHARS})"
        raise ImageFormatError(msg)
    original: str | None = None
    coded = text.strip()
    if ";" in coded:
        left, _, coded = coded.partition(";")
        original = left.strip().lower() or None
    words = coded.split()
    if not words:
        return ImageFormat(None, original)
    codec = _CODEC_NAMES.get(words[0].lower())
    if codec is None:
        msg = f"format {text[:40]!r} is neither JPEG nor PNG"
        raise ImageFormatError(msg)
    return ImageFormat(codec, original)


def _codec_of(data: bytes, stated: Codec | None) -> Codec:
    for codec, magic in _MAGIC.items():
        if data.startswith(magic):
            if stated is not None and stated != codec:
                msg = f"format says {stated} but the bytes are {codec}"
                raise CorruptImageError(msg)
            return codec
    if not data:
        msg = "no image bytes"
        raise TruncatedImageError(msg)
    if stated is None:
        msg = "empty format and the bytes are neither JPEG nor PNG"
        raise ImageFormatError(msg)
    msg = f"format says {stated} but the bytes do not start as {stated} does"
    raise CorruptImageError(msg)


def check_declared_size(data: bytes, codec: Codec, max_pixels: int) -> tuple[int, int]:
    """``(width, height)`` the image declares, after checking that it is whole and not over
    ``max_pixels``; nothing is decoded.

    Raises:
        TruncatedImageError: the image does not end as ``codec`` ends.
        CorruptImageError: no size can be read from its header.
        DimensionError: a side over MAX_DIMENSION.
        TooManyPixelsError: more than ``max_pixels`` pixels.

    """
    if not data.endswith(_END[codec]):
        msg = f"{codec} of {len(data)} bytes without its end of image"
        raise TruncatedImageError(msg)
    size = image_header_size(data)
    if size is None:
        msg = f"no image size in the {codec} header"
        raise CorruptImageError(msg)
    width, height = size
    if width > MAX_DIMENSION or height > MAX_DIMENSION:
        msg = f"declared {width}x{height} outside 1..{MAX_DIMENSION}"
        raise DimensionError(msg)
    if width * height > max_pixels:
        msg = (
            f"declared {width}x{height} = {width * height} pixels exceeds "
            f"max_frame_pixels = {max_pixels}"
        )
        raise TooManyPixelsError(msg)
    return width, height


def decode_compressed_cdr(
    payload: bytes | memoryview, *, max_pixels: int = MAX_PIXELS, grey: bool = False
) -> Frame:
    """Decode a sensor_msgs/msg/CompressedImage CDR sample to a BGR frame, with the header's
    stamp and frame id; to a grey one with ``grey`` or when its format says the camera's
    encoding was mono8 (a JPEG decodes to grey in about half the time of colour and a
    conversion: the detector needs no more).

    Raises:
        FrameDecodeError: a subclass naming what is wrong (see the module documentation).

    """
    msg = deserialize(payload, COMPRESSED_IMAGE_TYPE, CompressedImageCdrError)
    fmt = parse_format(str(msg.format))
    stamp_ns = check_stamp(stamp_ns_of(msg.header))
    buffer: Pixels = msg.data
    data = buffer.tobytes()  # the compressed bytes: a small copy, for the header checks
    codec = _codec_of(data, fmt.codec)
    width, height = check_declared_size(data, codec, max_pixels)
    flags = cv2.IMREAD_IGNORE_ORIENTATION | (
        cv2.IMREAD_GRAYSCALE if grey or fmt.grey else cv2.IMREAD_COLOR
    )
    try:
        decoded = cv2.imdecode(buffer, flags)
    except cv2.error as err:
        text = f"OpenCV cannot decode the {codec}: {err}"
        raise CorruptImageError(text) from err
    if decoded is None:
        text = f"OpenCV cannot decode the {codec}"
        raise CorruptImageError(text)
    pixels = cast(Pixels, decoded)
    if pixels.shape[:2] != (height, width):
        text = f"decoded {pixels.shape[1]}x{pixels.shape[0]}, declared {width}x{height}"
        raise CorruptImageError(text)
    encoding = ENCODINGS["mono8" if pixels.ndim == 2 else "bgr8"]
    frame_id = str(msg.header.frame_id)[:MAX_FRAME_ID_CHARS]
    return Frame(pixels, encoding, stamp_ns, frame_id, None)


def compressed_format(encoding: str, codec: Codec) -> str:
    """The ``format`` image_transport writes for a frame of ``encoding`` compressed with
    ``codec``: grey stays grey, anything else is encoded as BGR."""
    target = "mono8" if encoding == "mono8" else "bgr8"
    return f"{encoding}; {codec} compressed {target}"


def encode_compressed_frame(
    frame: Frame, codec: Codec, *, stamp_ns: int, frame_id: str, jpeg_quality: int = 90
) -> memoryview:
    """``frame`` compressed as image_transport's ``compressed`` plugin would publish it.

    Raises:
        ValueError: OpenCV could not encode the frame.

    """
    grey = frame.encoding.name == "mono8"
    pixels = np.ascontiguousarray(frame.pixels) if grey else to_bgr(frame)
    if codec == "jpeg":
        ok, encoded = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    else:
        ok, encoded = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - imencode only fails on invalid images
        msg = f"{codec} encoding failed"
        raise ValueError(msg)
    message = TYPESTORE.types[COMPRESSED_IMAGE_TYPE](
        header=header(stamp_ns, frame_id),
        format=compressed_format(frame.encoding.name, codec),
        data=np.asarray(encoded, dtype=np.uint8).reshape(-1),
    )
    raw: memoryview = TYPESTORE.serialize_cdr(message, COMPRESSED_IMAGE_TYPE)
    return raw


def compressed_image_data(payload: bytes | memoryview) -> tuple[str, bytes]:
    """The ``format`` and encoded bytes of a CompressedImage CDR sample (no decoding).

    Raises:
        CompressedImageCdrError: not a CompressedImage CDR sample.

    """
    msg = deserialize(payload, COMPRESSED_IMAGE_TYPE, CompressedImageCdrError)
    data: Pixels = msg.data
    return str(msg.format), data.tobytes()
