"""Frame decoding: raw + attachment and sensor_msgs/Image CDR, good and hostile input, and
CDR from rosbags (the reference implementation here) for every encoding, padding and byte order."""

from __future__ import annotations

import json
from typing import Any

import cv2
import jsonschema
import msgpack
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.helpers import REPO
from zenoh_perception.errors import (
    AttachmentError,
    DimensionError,
    FrameDecodeError,
    ImageCdrError,
    PayloadTooLargeError,
    SizeMismatchError,
    StampError,
    TooManyPixelsError,
    UnsupportedEncodingError,
)
from zenoh_perception.wire.frames import (
    ENCODINGS,
    MAX_ATTACHMENT_BYTES,
    MAX_STAMP_NS,
    RawFrameMeta,
    check_payload_size,
    decode_attachment,
    decode_image_cdr,
    decode_raw_frame,
    encode_image_cdr,
    to_gray,
)
from zenoh_perception.wire.messages import (
    IMAGE_TYPE,
    TYPESTORE,
    header,
)


def _pixels(height: int, width: int, channels: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (height, width) if channels == 1 else (height, width, channels)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


def _padded(pixels: np.ndarray, step: int) -> bytes:
    height = pixels.shape[0]
    rows = pixels.reshape(height, -1)
    out = np.full((height, step), 0xAB, dtype=np.uint8)
    out[:, : rows.shape[1]] = rows
    return out.tobytes()


# -- raw frames ------------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("padding", [0, 3, 64])
def test_raw_frame_is_a_view_of_the_payload(encoding: str, padding: int) -> None:
    channels = ENCODINGS[encoding].channels
    pixels = _pixels(7, 11, channels)
    step = 11 * channels + padding
    payload = _padded(pixels, step)
    meta = RawFrameMeta(11, 7, encoding, step=step, stamp_ns=42, frame_id="cam", seq=9)
    frame = decode_raw_frame(payload, meta.to_msgpack())
    np.testing.assert_array_equal(frame.pixels, pixels)
    assert np.shares_memory(frame.pixels, np.frombuffer(payload, dtype=np.uint8))
    assert (frame.width, frame.height, frame.stamp_ns, frame.frame_id, frame.seq) == (
        11,
        7,
        42,
        "cam",
        9,
    )
    assert not frame.pixels.flags.writeable


def test_attachment_defaults_to_bgra8_without_step() -> None:
    pixels = _pixels(4, 5, 4)
    frame = decode_raw_frame(pixels.tobytes(), msgpack.packb({"width": 5, "height": 4}))
    assert frame.encoding.name == "bgra8"
    assert frame.stamp_ns is None and frame.seq is None and frame.frame_id == ""
    np.testing.assert_array_equal(frame.pixels, pixels)


@pytest.mark.parametrize(
    ("attachment", "error"),
    [
        (None, AttachmentError),
        (b"", AttachmentError),
        (b"\xc1", AttachmentError),  # never-used msgpack byte
        (msgpack.packb([1, 2, 3]), AttachmentError),
        (msgpack.packb({"height": 4}), AttachmentError),
        (msgpack.packb({"width": "5", "height": 4}), AttachmentError),
        (msgpack.packb({"width": True, "height": 4}), AttachmentError),
        (msgpack.packb({"width": 5.0, "height": 4}), AttachmentError),
        (msgpack.packb({"width": 5, "height": 4, "encoding": 3}), AttachmentError),
        (msgpack.packb({"width": 5, "height": 4, "stamp_ns": -1}), StampError),
        (msgpack.packb({"width": 5, "height": 4, "stamp_ns": 2**63}), StampError),
        (msgpack.packb({"width": 5, "height": 4, "frame_id": "x" * 300}), AttachmentError),
        (
            msgpack.packb({"width": 5, "height": 4, "x": "y" * MAX_ATTACHMENT_BYTES}),
            AttachmentError,
        ),
        (msgpack.packb({"width": 5, "height": 4, "encoding": "yuv422"}), UnsupportedEncodingError),
        (msgpack.packb({"width": 0, "height": 4}), DimensionError),
        (msgpack.packb({"width": -5, "height": 4}), DimensionError),
        (msgpack.packb({"width": 5, "height": 1 << 40}), DimensionError),
        (msgpack.packb({"width": 5, "height": 4, "step": 19}), DimensionError),
        (msgpack.packb({"width": 5, "height": 4, "step": 1 << 40}), DimensionError),
        (msgpack.packb({"width": 5, "height": 5}), SizeMismatchError),
        (msgpack.packb({"width": 5, "height": 4, "step": 24}), SizeMismatchError),
    ],
)
def test_inconsistent_raw_frames_are_rejected_with_their_reason(
    attachment: bytes | None, error: type[FrameDecodeError]
) -> None:
    payload = bytes(5 * 4 * 4)
    with pytest.raises(error) as info:
        decode_raw_frame(payload, attachment)
    assert info.value.reason == error.reason


def test_reasons_are_distinct_per_concern() -> None:
    classes = (
        AttachmentError,
        ImageCdrError,
        UnsupportedEncodingError,
        DimensionError,
        SizeMismatchError,
        PayloadTooLargeError,
        TooManyPixelsError,
        StampError,
    )
    assert len({cls.reason for cls in classes}) == len(classes)


def test_frames_over_the_pixel_limit_are_refused_raw_and_cdr_alike() -> None:
    pixels = _pixels(30, 40, 1)  # 1200 pixels
    meta = RawFrameMeta(40, 30, "mono8").to_msgpack()
    cdr = bytes(encode_image_cdr(pixels, "mono8"))
    assert decode_raw_frame(pixels.tobytes(), meta, max_pixels=1200).width == 40
    assert decode_image_cdr(cdr, max_pixels=1200).width == 40
    with pytest.raises(TooManyPixelsError, match="max_frame_pixels = 1199"):
        decode_raw_frame(pixels.tobytes(), meta, max_pixels=1199)
    with pytest.raises(TooManyPixelsError):
        decode_image_cdr(cdr, max_pixels=1199)
    # A header that lies about its size is a size mismatch, whatever it claims.
    with pytest.raises(SizeMismatchError):
        decode_raw_frame(bytes(10), RawFrameMeta(4000, 3000, "mono8").to_msgpack(), max_pixels=1)


def test_payload_size_limit() -> None:
    check_payload_size(1024, 1024)
    with pytest.raises(PayloadTooLargeError, match="1025 bytes exceeds max_frame_bytes = 1024"):
        check_payload_size(1025, 1024)


def _cdr_with_stamp(sec: int, nanosec: int) -> bytes:
    """Image CDR whose header carries (sec, nanosec) exactly (negative seconds included)."""
    good: Any = TYPESTORE.deserialize_cdr(
        encode_image_cdr(_pixels(2, 3, 4), "bgra8", frame_id="f"), "sensor_msgs/msg/Image"
    )
    types = TYPESTORE.types
    good.header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="f"
    )
    return bytes(TYPESTORE.serialize_cdr(good, "sensor_msgs/msg/Image"))


def test_negative_stamps_are_refused_raw_and_cdr_alike() -> None:
    """One rule for both inputs: a stamp before the epoch is a bad_stamp rejection."""
    pixels = _pixels(2, 3, 4)
    raw_meta = msgpack.packb({"width": 3, "height": 2, "stamp_ns": -1})
    with pytest.raises(StampError) as raw:
        decode_raw_frame(pixels.tobytes(), raw_meta)
    with pytest.raises(StampError) as cdr:
        decode_image_cdr(_cdr_with_stamp(-1, 999_999_999))  # -1 ns
    assert raw.value.reason == cdr.value.reason == "bad_stamp"
    # Stamp 0 and the largest CDR stamp are accepted by both.
    zero = msgpack.packb({"width": 3, "height": 2, "stamp_ns": 0})
    assert decode_raw_frame(pixels.tobytes(), zero).stamp_ns == 0
    assert decode_image_cdr(_cdr_with_stamp(0, 0)).stamp_ns == 0
    last = _cdr_with_stamp(2**31 - 1, 999_999_999)
    assert decode_image_cdr(last).stamp_ns == (2**31 - 1) * 10**9 + 999_999_999
    big = msgpack.packb({"width": 3, "height": 2, "stamp_ns": MAX_STAMP_NS})
    assert decode_raw_frame(pixels.tobytes(), big).stamp_ns == MAX_STAMP_NS


def test_attachment_roundtrip_keeps_every_field() -> None:
    meta = RawFrameMeta(1280, 720, "rgb8", step=3840, stamp_ns=1, frame_id="zed", seq=3)
    assert decode_attachment(meta.to_msgpack()) == meta


def _schema(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((REPO / "schemas" / name).read_text())
    jsonschema.Draft202012Validator.check_schema(data)
    return data


def test_attachment_schema_agrees_with_the_decoder() -> None:
    schema = _schema("frame-attachment.schema.json")
    meta = RawFrameMeta(640, 480, "bgr8", step=1920, stamp_ns=5, frame_id="cam", seq=3)
    jsonschema.validate(msgpack.unpackb(meta.to_msgpack()), schema)
    assert decode_attachment(meta.to_msgpack()) == meta
    assert set(schema["properties"]["encoding"]["enum"]) == {
        "bgra8",
        "bgr8",
        "rgba8",
        "rgb8",
        "mono8",
    }


# -- sensor_msgs/Image CDR -------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("padding", [0, 4])
def test_cdr_image_roundtrip_is_zero_copy(encoding: str, padding: int) -> None:
    channels = ENCODINGS[encoding].channels
    pixels = _pixels(6, 10, channels, seed=3)
    raw = bytes(
        encode_image_cdr(
            pixels,
            encoding,
            stamp_ns=1_700_000_000_123_456_789,
            frame_id="zed_left",
            step=10 * channels + padding,
        )
    )
    frame = decode_image_cdr(raw)
    np.testing.assert_array_equal(frame.pixels, pixels)
    assert frame.stamp_ns == 1_700_000_000_123_456_789
    assert frame.frame_id == "zed_left"
    assert np.shares_memory(frame.pixels, np.frombuffer(raw, dtype=np.uint8))


def _good_cdr() -> bytes:
    return bytes(encode_image_cdr(_pixels(4, 6, 4), "bgra8", stamp_ns=5, frame_id="f"))


@pytest.mark.parametrize("cut", [0, 3, 4, 10, 30, 60, -1])
def test_truncated_cdr_is_rejected(cut: int) -> None:
    raw = _good_cdr()
    with pytest.raises(ImageCdrError):
        decode_image_cdr(raw[:cut])


def test_cdr_with_trailing_garbage_is_rejected() -> None:
    with pytest.raises(ImageCdrError):
        decode_image_cdr(_good_cdr() + b"\x00" * 8)


def test_cdr_with_unknown_encoding_is_rejected() -> None:
    raw = bytes(encode_image_cdr(_pixels(2, 2, 3), "bgr8"))
    tampered = raw.replace(b"bgr8", b"yuv8")
    with pytest.raises(UnsupportedEncodingError):
        decode_image_cdr(tampered)


def test_cdr_whose_step_and_data_disagree_is_rejected() -> None:
    # A 4x6 bgra8 image claiming 7 rows: data holds 96 bytes, step * height needs 168.
    raw = bytearray(_good_cdr())
    height_at = raw.index((4).to_bytes(4, "little") + (6).to_bytes(4, "little"))
    raw[height_at : height_at + 4] = (7).to_bytes(4, "little")
    with pytest.raises(SizeMismatchError):
        decode_image_cdr(bytes(raw))


Pixels = npt.NDArray[np.uint8]


# -- sensor_msgs/Image CDR from rosbags (the reference implementation here) ------------------------


def _rosbags_image_cdr(
    pixels: Pixels,
    encoding: str,
    *,
    padding: int,
    little_endian: bool,
    stamp_ns: int = 1_700_000_001_000_000_123,
    frame_id: str = "zed_left_camera_optical_frame",
    pad_byte: int = 0xA5,
) -> bytes:
    """Image CDR built and serialised by rosbags; rows padded with ``pad_byte``."""
    height, width = pixels.shape[:2]
    row = pixels.reshape(height, -1)
    step = row.shape[1] + padding
    data = np.full((height, step), pad_byte, dtype=np.uint8)
    data[:, : row.shape[1]] = row
    types = TYPESTORE.types
    msg = types[IMAGE_TYPE](
        header=header(stamp_ns, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=data.reshape(-1),
    )
    return bytes(TYPESTORE.serialize_cdr(msg, IMAGE_TYPE, little_endian=little_endian))


def _random_pixels(height: int, width: int, channels: int, seed: int) -> Pixels:
    rng = np.random.default_rng(seed)
    shape = (height, width) if channels == 1 else (height, width, channels)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


ENDIANNESS = pytest.mark.parametrize("little_endian", [True, False], ids=["le", "be"])


ENDIANNESS = pytest.mark.parametrize("little_endian", [True, False], ids=["le", "be"])
PADDING = pytest.mark.parametrize("padding", [0, 1, 3, 64])


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@PADDING
@ENDIANNESS
@pytest.mark.parametrize(("height", "width"), [(7, 13), (48, 64)])
def test_rosbags_image_decodes_to_the_same_pixels(
    encoding: str, padding: int, little_endian: bool, height: int, width: int
) -> None:
    pixels = _random_pixels(height, width, ENCODINGS[encoding].channels, seed=height + padding)
    payload = _rosbags_image_cdr(pixels, encoding, padding=padding, little_endian=little_endian)
    assert payload[:2] == (b"\x00\x01" if little_endian else b"\x00\x00")
    frame = decode_image_cdr(payload)
    assert frame.encoding.name == encoding
    assert (frame.width, frame.height) == (width, height)
    assert frame.pixels.shape == pixels.shape
    np.testing.assert_array_equal(frame.pixels, pixels)
    assert frame.stamp_ns == 1_700_000_001_000_000_123
    assert frame.frame_id == "zed_left_camera_optical_frame"


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("padding", [0, 8])
def test_encode_image_cdr_is_byte_identical_to_rosbags(encoding: str, padding: int) -> None:
    pixels = _random_pixels(5, 9, ENCODINGS[encoding].channels, seed=3)
    row_bytes = 9 * ENCODINGS[encoding].channels
    ours = encode_image_cdr(
        pixels,
        encoding,
        stamp_ns=1_700_000_001_000_000_123,
        frame_id="zed_left_camera_optical_frame",
        step=row_bytes + padding,
    )
    reference = _rosbags_image_cdr(
        pixels, encoding, padding=padding, little_endian=True, pad_byte=0
    )
    assert bytes(ours) == reference


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
# -- grey conversion -------------------------------------------------------------------------------


def test_gray_conversion_matches_the_bgr_reference(encoding: str) -> None:
    import cv2

    bgr = _pixels(8, 9, 3, seed=5)
    converters = {
        "bgra8": cv2.COLOR_BGR2BGRA,
        "bgr8": None,
        "rgba8": cv2.COLOR_BGR2RGBA,
        "rgb8": cv2.COLOR_BGR2RGB,
        "mono8": cv2.COLOR_BGR2GRAY,
    }
    code = converters[encoding]
    pixels = bgr if code is None else cv2.cvtColor(bgr, code)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    frame = decode_raw_frame(
        _padded(pixels, pixels.reshape(8, -1).shape[1] + 8),
        RawFrameMeta(9, 8, encoding, step=pixels.reshape(8, -1).shape[1] + 8).to_msgpack(),
    )
    np.testing.assert_array_equal(to_gray(frame), expected)


def _as_encoding(bgr: Pixels, encoding: str, seed: int) -> Pixels:
    """The same picture in ``encoding`` (alpha random: it must not affect grey)."""
    alpha = _random_pixels(bgr.shape[0], bgr.shape[1], 1, seed)
    if encoding == "bgr8":
        return bgr
    if encoding == "rgb8":
        return np.ascontiguousarray(bgr[:, :, ::-1])
    if encoding == "bgra8":
        return np.dstack([bgr, alpha])
    if encoding == "rgba8":
        return np.dstack([bgr[:, :, ::-1], alpha])
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), dtype=np.uint8)  # mono8


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
@pytest.mark.parametrize("padding", [0, 5])
@ENDIANNESS
def test_grey_from_every_encoding_matches_opencv_on_bgr(
    encoding: str, padding: int, little_endian: bool
) -> None:
    bgr = _random_pixels(31, 47, 3, seed=11)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    pixels = _as_encoding(bgr, encoding, seed=12)
    frame = decode_image_cdr(
        _rosbags_image_cdr(pixels, encoding, padding=padding, little_endian=little_endian)
    )
    gray = to_gray(frame)
    assert gray.shape == (31, 47)
    np.testing.assert_array_equal(gray, expected)


# -- properties: any bytes give a frame or the typed error, never another exception ----------------


@given(payload=st.binary(max_size=256), attachment=st.one_of(st.none(), st.binary(max_size=64)))
def test_raw_decoder_never_raises_anything_but_frame_errors(
    payload: bytes, attachment: bytes | None
) -> None:
    try:
        frame = decode_raw_frame(payload, attachment)
    except FrameDecodeError:
        return
    # Anything accepted is fully backed by the payload.
    assert frame.pixels.nbytes <= len(payload)


_attachment_values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True),
    st.text(max_size=8),
    st.binary(max_size=8),
    st.lists(st.integers(min_value=-(2**63), max_value=2**63 - 1), max_size=3),
)


@given(
    fields=st.dictionaries(
        st.sampled_from(
            ["width", "height", "encoding", "step", "stamp_ns", "frame_id", "seq", "x"]
        ),
        _attachment_values,
    ),
    size=st.integers(min_value=0, max_value=512),
)
def test_structured_attachments_give_a_frame_or_a_typed_error(
    fields: dict[str, object], size: int
) -> None:
    payload = bytes(size)
    try:
        frame = decode_raw_frame(payload, msgpack.packb(fields))
    except FrameDecodeError:
        return
    assert frame.pixels.nbytes <= size
    assert frame.width == fields["width"] and frame.height == fields["height"]


@given(data=st.data())
def test_mutated_cdr_gives_a_frame_or_a_typed_error(data: st.DataObject) -> None:
    raw = bytearray(_good_cdr())
    for _ in range(data.draw(st.integers(min_value=1, max_value=6))):
        index = data.draw(st.integers(min_value=0, max_value=len(raw) - 1))
        raw[index] = data.draw(st.integers(min_value=0, max_value=255))
    cut = data.draw(st.integers(min_value=0, max_value=len(raw)))
    try:
        frame = decode_image_cdr(bytes(raw[:cut]))
    except FrameDecodeError:
        return
    assert frame.pixels.nbytes <= cut


@given(payload=st.binary(max_size=512))
def test_arbitrary_cdr_bytes_give_a_frame_or_a_typed_error(payload: bytes) -> None:
    try:
        frame = decode_image_cdr(payload)
    except FrameDecodeError:
        return
    assert frame.pixels.nbytes <= len(payload)
