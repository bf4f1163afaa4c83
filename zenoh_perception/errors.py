"""Typed errors, one class per concern.

Every error a network payload can cause derives from :class:`FrameDecodeError` and carries a
stable ``reason`` string; the service counts rejections by that reason and names it in its log.
"""

from __future__ import annotations


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


class MessageDecodeError(PerceptionError):
    """An output message (tag CDR or perception record) could not be decoded."""
