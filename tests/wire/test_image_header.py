"""The declared size of PNG and JPEG images, read from their headers: what OpenCV itself
decodes for real files, the declared size (never a wrong one) for hostile or cut ones."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zenoh_perception.wire.image_header import image_header_size


def _encode(ext: str, width: int, height: int, channels: int, params: list[int]) -> bytes:
    shape = (height, width) if channels == 1 else (height, width, channels)
    image = np.random.default_rng(width * 131 + height).integers(0, 256, shape, dtype=np.uint8)
    ok, data = cv2.imencode(ext, image, params)
    assert ok
    return bytes(data)


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_declaring(width: int, height: int) -> bytes:
    """A tiny PNG whose IHDR declares ``width`` x ``height`` 8-bit RGB (no image data)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IEND", b"")


def jpeg_declaring(width: int, height: int, sof: int = 0xC0, before: bytes = b"") -> bytes:
    """SOI, ``before`` (segments), then an SOFn declaring ``width`` x ``height``, then EOI."""
    sof_body = struct.pack(">BHHB", 8, height, width, 1) + b"\x01\x11\x00"
    segment = b"\xff" + bytes([sof]) + struct.pack(">H", len(sof_body) + 2) + sof_body
    return b"\xff\xd8" + before + segment + b"\xff\xd9"


@given(
    width=st.integers(1, 48),
    height=st.integers(1, 48),
    channels=st.sampled_from([1, 3]),
    ext=st.sampled_from([".png", ".jpg"]),
    progressive=st.booleans(),
)
def test_the_size_opencv_writes_is_the_size_read(
    width: int, height: int, channels: int, ext: str, progressive: bool
) -> None:
    params = [cv2.IMWRITE_JPEG_PROGRESSIVE, int(progressive)] if ext == ".jpg" else []
    data = _encode(ext, width, height, channels, params)
    assert image_header_size(data) == (width, height)
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded is not None
    assert decoded.shape[:2] == (height, width)


@given(width=st.integers(1, 2**31 - 1), height=st.integers(1, 2**31 - 1))
def test_a_png_declares_its_size_in_ihdr_whatever_it_holds(width: int, height: int) -> None:
    assert image_header_size(png_declaring(width, height)) == (width, height)


@given(
    width=st.integers(1, 65535),
    height=st.integers(1, 65535),
    sof=st.sampled_from([m for m in range(0xC0, 0xD0) if m not in (0xC4, 0xC8, 0xCC)]),
)
def test_every_start_of_frame_marker_declares_the_size(width: int, height: int, sof: int) -> None:
    assert image_header_size(jpeg_declaring(width, height, sof)) == (width, height)


@pytest.mark.parametrize("marker", [0xC4, 0xC8, 0xCC])
def test_dht_jpg_and_dac_segments_are_skipped_not_read_as_a_size(marker: int) -> None:
    # A segment in the SOF range that is not one: its bytes would read as 4112 x 4112.
    decoy_body = bytes([8, 0x10, 0x10, 0x10, 0x10, 1, 1, 0x11, 0])
    decoy = b"\xff" + bytes([marker]) + struct.pack(">H", len(decoy_body) + 2) + decoy_body
    assert image_header_size(jpeg_declaring(64, 32, before=decoy)) == (64, 32)


def test_fill_bytes_and_app_segments_before_the_frame_are_skipped() -> None:
    app0 = b"\xff\xe0" + struct.pack(">H", 16) + b"JFIF\x00" + bytes(9)
    restart = b"\xff\xd3"  # standalone: no length
    assert image_header_size(jpeg_declaring(7, 9, before=app0 + b"\xff\xff" + restart)) == (7, 9)


def test_the_png_bomb_declares_its_size_in_a_few_bytes() -> None:
    bomb = png_declaring(16000, 16000)
    assert len(bomb) < 64
    assert image_header_size(bomb) == (16000, 16000)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"GIF89a\x01\x00\x01\x00",
        b"\x89PNG\r\n\x1a\n",  # signature only
        png_declaring(0, 10),  # zero side
        png_declaring(10, 20)[:8] + b"\x00\x00\x00\x0dIHDX" + bytes(13),  # not IHDR first
        b"\xff\xd8",  # SOI only
        b"\xff\xd8\xff\xda\x00\x02",  # scan data before any frame header
        b"\xff\xd8\xff\xd9",  # EOI before any frame header
        b"\xff\xd8\x00\x00",  # garbage where a marker must be
        b"\xff\xd8\xff\xe0\x00\x01",  # a length shorter than itself
        jpeg_declaring(10, 0),  # height deferred to a DNL segment
    ],
)
def test_what_declares_no_readable_size_is_none(data: bytes) -> None:
    assert image_header_size(data) is None


@given(
    ext=st.sampled_from([".png", ".jpg"]),
    cut=st.integers(0, 400),
)
def test_a_cut_header_gives_none_or_the_true_size(ext: str, cut: int) -> None:
    data = _encode(ext, 33, 17, 3, [])
    assert image_header_size(data[:cut]) in (None, (33, 17))


@given(st.binary(max_size=256))
def test_any_bytes_give_a_size_or_none(data: bytes) -> None:
    size = image_header_size(data)
    assert size is None or (size[0] > 0 and size[1] > 0)


@given(st.binary(max_size=128))
def test_any_bytes_after_the_jpeg_soi_give_a_size_or_none(tail: bytes) -> None:
    size = image_header_size(b"\xff\xd8" + tail)
    assert size is None or (0 < size[0] <= 65535 and 0 < size[1] <= 65535)


def _encoded(ext: str, width: int, height: int) -> bytes:
    image = np.zeros((height, width, 3), np.uint8)
    image[::3, ::2] = 255
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def _png_declaring(width: int, height: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return (
        b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))
    )


def test_other_and_broken_headers_give_none() -> None:
    assert image_header_size(b"") is None
    assert image_header_size(b"GIF89a\x01\x00\x01\x00") is None
    assert image_header_size(_encoded(".bmp", 4, 4)) is None
    assert image_header_size(_png_declaring(0, 5)) is None
    assert image_header_size(_png_declaring(2**31, 5)) is None
    assert image_header_size(b"\xff\xd8\xff\xda\x00\x08") is None  # scan before a frame header
    assert image_header_size(b"\xff\xd8\xff\xc0\x00\x01") is None  # segment length under 2
    assert image_header_size(b"\xff\xd8\x12\x34") is None  # no marker where one must be


@settings(max_examples=300, deadline=None)
@given(
    ext=st.sampled_from([".png", ".jpg"]),
    at=st.integers(0, 400),
    noise=st.binary(min_size=1, max_size=8),
)
def test_a_corrupt_header_never_raises(ext: str, at: int, noise: bytes) -> None:
    data = bytearray(_encoded(ext, 23, 17))
    data[at : at + len(noise)] = noise
    size = image_header_size(bytes(data))
    assert size is None or (size[0] > 0 and size[1] > 0)
