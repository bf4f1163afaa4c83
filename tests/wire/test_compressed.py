"""Compressed frames: image_transport's CompressedImage CDR decoded to pixels, every hostile
payload a rejection with its reason, and replay's encoder read back by the decoder."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.wire.test_image_header import png_declaring
from zenoh_perception.errors import FrameDecodeError
from zenoh_perception.wire.compressed import (
    compressed_image_data,
    decode_compressed_cdr,
    encode_compressed_frame,
    parse_format,
)
from zenoh_perception.wire.frames import ENCODINGS, Frame
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE, TYPESTORE, header


def compressed_cdr(
    data: bytes, fmt: str, *, stamp_ns: int = 5_000_000_123, frame_id: str = "cam"
) -> bytes:
    message = TYPESTORE.types[COMPRESSED_IMAGE_TYPE](
        header=header(stamp_ns, frame_id), format=fmt, data=np.frombuffer(data, np.uint8)
    )
    return bytes(TYPESTORE.serialize_cdr(message, COMPRESSED_IMAGE_TYPE))


def _picture(width: int = 64, height: int = 48) -> np.ndarray:
    image = np.zeros((height, width, 3), np.uint8)
    image[:, : width // 2] = (255, 0, 0)  # blue left half (BGR)
    image[:, width // 2 :] = (0, 0, 255)  # red right half
    return image


def _encoded(ext: str, image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(ext, image)
    assert ok
    return bytes(data)


@pytest.mark.parametrize(
    ("fmt", "ext"),
    [
        ("jpeg", ".jpg"),
        ("bgr8; jpeg compressed bgr8", ".jpg"),
        ("rgb8; jpeg compressed bgr8", ".jpg"),
        ("png", ".png"),
        ("bgra8; png compressed bgr8", ".png"),
        ("", ".png"),  # no format: the bytes say which
    ],
)
def test_image_transport_formats_decode_to_bgr_with_the_header(fmt: str, ext: str) -> None:
    frame = decode_compressed_cdr(compressed_cdr(_encoded(ext, _picture()), fmt))
    assert (frame.width, frame.height, frame.encoding.name) == (64, 48, "bgr8")
    assert (frame.stamp_ns, frame.frame_id) == (5_000_000_123, "cam")
    b, _, r = (int(v) for v in frame.pixels[24, 8])
    assert b > 200 and r < 50  # blue stays blue: decoded as BGR whatever the camera's order
    b, _, r = (int(v) for v in frame.pixels[24, 56])
    assert r > 200 and b < 50


def test_a_mono8_png_decodes_to_grey() -> None:
    grey = np.tile(np.arange(64, dtype=np.uint8) * 4, (32, 1))
    frame = decode_compressed_cdr(
        compressed_cdr(_encoded(".png", grey), "mono8; png compressed mono8")
    )
    assert frame.encoding.name == "mono8"
    assert np.array_equal(frame.pixels, grey)


@pytest.mark.parametrize(("ext", "fmt"), [(".jpg", "jpeg"), (".png", "png")])
def test_a_colour_frame_decodes_straight_to_grey_when_asked(ext: str, fmt: str) -> None:
    picture = _picture()
    frame = decode_compressed_cdr(compressed_cdr(_encoded(ext, picture), fmt), grey=True)
    assert (frame.encoding.name, frame.pixels.shape) == ("mono8", (48, 64))
    expected = cv2.cvtColor(picture, cv2.COLOR_BGR2GRAY).astype(int)
    assert np.abs(frame.pixels[:, :24].astype(int) - expected[:, :24]).max() < 8


def test_the_png_bomb_is_refused_from_its_header() -> None:
    payload = compressed_cdr(png_declaring(16000, 16000), "png")
    with pytest.raises(FrameDecodeError) as caught:
        decode_compressed_cdr(payload, max_pixels=4096 * 4096)
    assert caught.value.reason == "too_many_pixels"


@pytest.mark.parametrize(
    ("data", "fmt", "reason"),
    [
        (_encoded(".jpg", _picture())[:-300], "jpeg", "truncated_image"),
        (_encoded(".png", _picture())[:-20], "png", "truncated_image"),
        (b"", "jpeg", "truncated_image"),
        (_encoded(".jpg", _picture()), "16UC1; compressedDepth png", "unsupported_image_format"),
        (_encoded(".jpg", _picture()), "tiff", "unsupported_image_format"),
        (b"GIF89a" + bytes(40), "", "unsupported_image_format"),
        (_encoded(".png", _picture()), "jpeg", "corrupt_image"),  # not what the format says
        (b"\x00" * 64 + b"\xff\xd9", "jpeg", "corrupt_image"),
        (b"\xff\xd8\xff" + bytes(range(256)) * 4 + b"\xff\xd9", "jpeg", "corrupt_image"),
        (png_declaring(20000, 8), "png", "bad_dimensions"),
    ],
)
def test_hostile_compressed_frames_are_refused_by_reason(
    data: bytes, fmt: str, reason: str
) -> None:
    with pytest.raises(FrameDecodeError) as caught:
        decode_compressed_cdr(compressed_cdr(data, fmt))
    assert caught.value.reason == reason


def test_a_png_whose_data_is_garbage_is_corrupt() -> None:
    good = _encoded(".png", _picture())
    # keep the signature, IHDR and IEND; break the compressed pixel data (IDAT) in between
    idat = good.index(b"IDAT")
    bad = good[: idat + 8] + bytes(len(good) - idat - 8 - 12) + good[-12:]
    with pytest.raises(FrameDecodeError) as caught:
        decode_compressed_cdr(compressed_cdr(bad, "png"))
    assert caught.value.reason == "corrupt_image"


def test_not_compressed_image_cdr_is_bad_cdr() -> None:
    with pytest.raises(FrameDecodeError) as caught:
        decode_compressed_cdr(b"\x00\x01\x00\x00\x07")
    assert caught.value.reason == "bad_compressed_cdr"


@given(st.binary(max_size=200), st.sampled_from(["jpeg", "png", "", "bgr8; jpeg compressed bgr8"]))
def test_any_image_bytes_decode_or_are_refused_by_reason(data: bytes, fmt: str) -> None:
    try:
        decode_compressed_cdr(compressed_cdr(data, fmt))
    except FrameDecodeError as err:
        assert err.reason


@given(st.binary(max_size=300))
def test_any_payload_decodes_or_is_refused_by_reason(payload: bytes) -> None:
    try:
        decode_compressed_cdr(payload)
    except FrameDecodeError as err:
        assert err.reason


@pytest.mark.parametrize("encoding", ["bgra8", "rgb8", "mono8"])
@pytest.mark.parametrize("codec", ["jpeg", "png"])
def test_replays_encoder_writes_what_the_decoder_reads(encoding: str, codec: str) -> None:
    bgr = _picture()
    enc = ENCODINGS[encoding]
    if encoding == "mono8":
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    elif encoding == "rgb8":
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    else:
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)
    frame = Frame(np.asarray(pixels, np.uint8), enc, None, "", None)
    payload = encode_compressed_frame(frame, codec, stamp_ns=42, frame_id="zed_left")  # type: ignore[arg-type]
    fmt, _ = compressed_image_data(payload)
    target = "mono8" if encoding == "mono8" else "bgr8"
    assert fmt == f"{encoding}; {codec} compressed {target}"
    back = decode_compressed_cdr(payload)
    assert (back.stamp_ns, back.frame_id, back.encoding.name) == (42, "zed_left", target)
    expected = pixels if encoding == "mono8" else bgr
    error = np.abs(back.pixels.astype(int) - expected.astype(int))
    if codec == "png":
        assert error.max() == 0
    else:  # lossy, and chroma is subsampled at the colour edge: read away from it
        assert error[:, :24].max() < 40 and error[:, 40:].max() < 40


def test_parse_format_reads_the_original_encoding() -> None:
    fmt = parse_format("mono8; jpeg compressed mono8")
    assert (fmt.codec, fmt.original, fmt.grey) == ("jpeg", "mono8", True)
    assert parse_format("JPG").codec == "jpeg"
