"""The service's frame inputs: what each one's samples carry (:class:`InputKind`) and the
decoder bound to it when it is subscribed (:data:`DECODERS`), which input a concrete key's
samples come on, and what the stream a sample belongs to is named (:class:`StreamNaming`:
the one place that tells one camera from several)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Final

import zenoh

from zenoh_perception.errors import SettingsError
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.settings.sections import Inputs
from zenoh_perception.wire.compressed import decode_compressed_cdr
from zenoh_perception.wire.frames import Frame, decode_image_cdr, decode_raw_frame
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.ros_topics import input_role
from zenoh_perception.wire.stream_keys import StreamNames

RAW: Final = InputKind.RAW
CDR: Final = InputKind.CDR
COMPRESSED: Final = InputKind.COMPRESSED

#: A sample's payload and attachment to a frame, and the kind it was read as (the record's
#: source), at most ``max_pixels``; ``grey``: a compressed frame may decode to grey.
Decoder = Callable[[bytes, "zenoh.ZBytes | None", int, bool], tuple[Frame, InputKind]]


def _raw_or_cdr(
    payload: bytes, attachment: zenoh.ZBytes | None, max_pixels: int, _grey: bool
) -> tuple[Frame, InputKind]:
    if attachment is None:
        return decode_image_cdr(payload, max_pixels=max_pixels), CDR
    return decode_raw_frame(payload, attachment.to_bytes(), max_pixels=max_pixels), RAW


def _cdr(
    payload: bytes, _attachment: zenoh.ZBytes | None, max_pixels: int, _grey: bool
) -> tuple[Frame, InputKind]:
    # rmw_zenoh's attachment is its own (sequence number, GID), not a raw frame's
    return decode_image_cdr(payload, max_pixels=max_pixels), CDR


def _compressed(
    payload: bytes, _attachment: zenoh.ZBytes | None, max_pixels: int, grey: bool
) -> tuple[Frame, InputKind]:
    return decode_compressed_cdr(payload, max_pixels=max_pixels, grey=grey), COMPRESSED


#: The decoder of each input kind, bound to a subscription when it is declared.
DECODERS: Final[Mapping[InputKind, Decoder]] = {
    RAW: _raw_or_cdr,
    CDR: _cdr,
    COMPRESSED: _compressed,
}


def input_patterns(inputs: Inputs) -> dict[InputKind, StreamNames]:
    """How each input kind's keys name their streams."""
    patterns: dict[InputKind, StreamNames] = {}
    if inputs.input_key:
        patterns[RAW] = patterns[CDR] = StreamNames(inputs.input_key)
    if inputs.compressed_input_key:
        patterns[COMPRESSED] = StreamNames(inputs.compressed_input_key)
    return patterns


def kind_of(key: str, inputs: Inputs, ros: RosTransport) -> InputKind:
    """The input whose samples the concrete ``key`` carries.

    Raises:
        SettingsError: ``key`` is not concrete, or neither input matches it.

    """
    if "*" in key or "$" in key:
        msg = f"{key!r} is not a concrete key"
        raise SettingsError(msg)
    concrete = zenoh.KeyExpr(key)

    def matches(keys: list[str] | tuple[str, ...]) -> bool:
        return any(zenoh.KeyExpr(k).intersects(concrete) for k in keys)

    if inputs.input_key:
        if ros.rmw_zenoh and matches(ros.keys(input_role(CDR))):
            return CDR
        if matches(inputs.input_entries):
            return RAW
    if inputs.compressed_input_key and matches(ros.keys(input_role(COMPRESSED))):
        return COMPRESSED
    msg = f"{key!r} matches neither input_key nor compressed_input_key"
    raise SettingsError(msg)


class StreamNaming:
    """What the stream of a sample is named, and whether log lines name it.

    Every input is a list of cameras: a concrete ``input_key`` a list of one, whose one
    stream is named ``""``, known before any frame (:attr:`at_start`) and not named in log
    lines; a wildcard or a list of keys, a stream per concrete key it matches, named by the
    chunks where they differ (:mod:`~zenoh_perception.wire.stream_keys`), made on its first
    frame, at most ``max_streams`` of them.
    """

    def __init__(self, inputs: Inputs, ros: RosTransport) -> None:
        self._ros = ros
        self._patterns = input_patterns(inputs)
        self._info_names = StreamNames(inputs.camera_info_key)
        #: Log lines and the status name each stream (an input may have several).
        self.named = inputs.several
        #: The streams known before any frame: opened at start, never forgotten when idle.
        self.at_start: tuple[str, ...] = () if self.named else ("",)
        #: The most streams the service serves at once.
        self.most_streams = inputs.max_streams if self.named else 1

    def name(self, kind: InputKind, key: str) -> str | None:
        """The name of the stream ``key`` (a sample's key on input ``kind``) belongs to; None
        when it matches no input."""
        if not self.named:
            return ""
        topic = key if kind is RAW else self._ros.topic_of(key)
        names = self._patterns.get(kind)
        return None if names is None else names.name(topic)

    def of_camera_info(self, key: str) -> str:
        """The stream a CameraInfo on ``key`` is for (``""``: every stream)."""
        if not self.named:
            return ""
        return self._info_names.name(self._ros.topic_of(key)) or ""

    def fields(self, stream: str) -> dict[str, str]:
        """The field naming ``stream`` (its key or its name) in a log line about it: none
        when there is one stream."""
        return {"stream": stream} if self.named else {}
