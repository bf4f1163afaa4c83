"""Typed errors, one class per concern.

Every error a network payload can cause derives from :class:`FrameDecodeError` and carries a
stable ``reason`` string; the service counts rejections by that reason and names it in its log.
The other errors the service counts at run time (:class:`CameraInfoError`,
:class:`IntrinsicsError`, :class:`ProcessingError`) carry a ``reason`` too.
"""

from __future__ import annotations

import re


class PerceptionError(Exception):
    """Base class of every error raised by zenoh-perception."""


class SettingsError(PerceptionError):
    """The settings file or a settings flag is invalid."""


class FrameDecodeError(PerceptionError):
    """A frame payload could not be turned into pixels."""

    reason = "bad_frame"


class AttachmentError(FrameDecodeError):
    """The msgpack attachment of a raw frame is missing, malformed or incomplete."""

    reason = "bad_attachment"


class ImageCdrError(FrameDecodeError):
    """The payload is not a well-formed sensor_msgs/msg/Image CDR sample."""

    reason = "bad_cdr"


class UnsupportedEncodingError(FrameDecodeError):
    """The frame's pixel encoding is not one the service converts to grey."""

    reason = "unsupported_encoding"


class DimensionError(FrameDecodeError):
    """Width, height or step are zero, negative, absurd or inconsistent."""

    reason = "bad_dimensions"


class SizeMismatchError(FrameDecodeError):
    """The pixel buffer does not hold exactly ``step * height`` bytes."""

    reason = "size_mismatch"


class CompressedImageCdrError(FrameDecodeError):
    """The payload is not a well-formed sensor_msgs/msg/CompressedImage CDR sample."""

    reason = "bad_compressed_cdr"


class ImageFormatError(FrameDecodeError):
    """A compressed frame that is neither JPEG nor PNG, or whose bytes are not what its
    ``format`` says."""

    reason = "unsupported_image_format"


class TruncatedImageError(FrameDecodeError):
    """A compressed frame cut short: no readable size, or no end of image."""

    reason = "truncated_image"


class CorruptImageError(FrameDecodeError):
    """A compressed frame whose header or data OpenCV cannot decode."""

    reason = "corrupt_image"


class MessageDecodeError(PerceptionError):
    """An output message (tag CDR or perception record) could not be decoded; ``reason``
    says why (``undecodable`` unless a finer reason is given)."""

    reason = "undecodable"

    def __init__(self, *args: object, reason: str | None = None) -> None:
        super().__init__(*args)
        if reason is not None:
            self.reason = reason


class RmwZenohError(MessageDecodeError):
    """An rmw_zenoh attachment or liveliness token is not of rmw_zenoh's form."""

    reason = "bad_rmw_zenoh"


class PayloadTooLargeError(FrameDecodeError):
    """The frame payload holds more bytes than ``max_frame_bytes`` allows."""

    reason = "payload_too_large"


class TooManyPixelsError(FrameDecodeError):
    """The frame has more pixels than ``max_frame_pixels`` allows."""

    reason = "too_many_pixels"


class StampError(FrameDecodeError):
    """The frame's stamp is negative or beyond what a signed 64-bit nanosecond count holds."""

    reason = "bad_stamp"


class CameraInfoError(MessageDecodeError):
    """The payload is not a well-formed sensor_msgs/msg/CameraInfo CDR sample."""

    reason = "bad_camera_info"


class CameraInfoTooLargeError(CameraInfoError):
    """The CameraInfo payload is larger than any CameraInfo (refused before it is copied)."""

    reason = "camera_info_too_large"


class IntrinsicsError(PerceptionError):
    """Camera intrinsics outside plausible bounds (settings or CameraInfo)."""

    reason = "bad_intrinsics"


class ProcessingError(PerceptionError):
    """A decoded frame could not be turned into its outputs; ``stage`` says where it failed
    (``detect``, ``encode_tag``, ``encode_record``, ``debug_image``, ``second_look``)."""

    reason = "processing_error"

    def __init__(self, stage: str, detail: object) -> None:
        super().__init__(f"{stage}: {detail}")
        self.stage = stage


class JsonPayloadError(MessageDecodeError):
    """A JSON payload from the network (a status reply) is too large, too deeply nested, not
    JSON, or holds NaN or Infinity; ``reason`` says which."""

    def __init__(self, reason: str, detail: object) -> None:
        super().__init__(f"{reason}: {detail}", reason=reason)


class FrameAbandonedError(PerceptionError):
    """The detector did not finish a frame within the deadline (``frame_deadline_ms``), or
    the service stopped meanwhile: the frame was given up and the detector restarted.
    ``elapsed_ms`` is how long the frame ran."""

    reason = "abandoned"

    def __init__(self, elapsed_ms: float, deadline_ms: float) -> None:
        super().__init__(f"detection ran {elapsed_ms:.0f} ms (deadline {deadline_ms:g} ms)")
        self.elapsed_ms = elapsed_ms


class MissingPackageError(PerceptionError):
    """A command that needs the benchmark package (the benchmarks, the scene generator, the
    demo camera), which the service does not ship and is not installed."""

    def __init__(self, command: str) -> None:
        super().__init__(
            f"zenoh-perception {command} needs the benchmark package zenoh-perception-bench, "
            "which the service does not ship: from a checkout of zenoh-perception, "
            f"pip install -e ./bench (make {command} installs it)"
        )


class AnnouncementError(PerceptionError):
    """A liveliness token a share group does not trust: a camera announcement or a member
    token it ignores. ``reason`` (``not_concrete``, ``too_long``, ``no_match``, ...) is counted
    and named in the log; the group carries on."""

    def __init__(self, reason: str, key: str) -> None:
        super().__init__(f"{reason}: {key[:120]!r}")
        self.reason = reason
        self.key = key


class SessionError(PerceptionError):
    """A Zenoh session could not be opened (a listen port in use, a bad endpoint, ...)."""


#: Zenoh's JSON5 parse error, as its Rust debug form prints it.
_JSON5_ERROR = re.compile(
    r'Json5Err\(Message \{ msg: "(?P<msg>(?:[^"\\]|\\.)*)", location: '
    r"(?:Some\(Location \{ line: (?P<line>\d+), column: (?P<column>\d+) \}\)|None) \}\)"
)


def zenoh_error_text(err: Exception) -> str:
    """A Zenoh error as one readable line (without the Rust source locations it carries, and
    a JSON5 syntax error as its message and position rather than Rust's debug dump)."""
    text = re.sub(r"\s+at\s+\S+\.rs:\d+\.?", "", str(err))
    match = _JSON5_ERROR.search(text)
    if match is not None:
        detail = match["msg"].replace("\\n", "\n").rsplit("=", 1)[-1].strip()
        where = f" at line {match['line']}, column {match['column']}" if match["line"] else ""
        text = text.replace(match[0], f"not valid JSON5{where}: {detail}")
    return " ".join(text.split())
