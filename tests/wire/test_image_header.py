"""The size a PNG or JPEG header declares, read without decoding the picture."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from zenoh_perception.wire.image_header import image_header_size


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


def test_png_and_jpeg_sizes_are_read_from_their_headers() -> None:
    assert image_header_size(_encoded(".png", 37, 21)) == (37, 21)
    assert image_header_size(_encoded(".jpg", 64, 48)) == (64, 48)
    progressive = cv2.imencode(
        ".jpg", np.zeros((10, 30, 3), np.uint8), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]
    )[1].tobytes()
    assert image_header_size(progressive) == (30, 10)


def test_a_huge_declared_png_is_read_from_a_few_bytes() -> None:
    # what OpenCV would allocate gigabytes for, from 33 bytes
    assert image_header_size(_png_declaring(16000, 16000)) == (16000, 16000)


def test_other_and_broken_headers_give_none() -> None:
    assert image_header_size(b"") is None
    assert image_header_size(b"GIF89a\x01\x00\x01\x00") is None
    assert image_header_size(_encoded(".bmp", 4, 4)) is None
    assert image_header_size(_png_declaring(0, 5)) is None
    assert image_header_size(_png_declaring(2**31, 5)) is None
    assert image_header_size(b"\xff\xd8\xff\xda\x00\x08") is None  # scan before a frame header
    assert image_header_size(b"\xff\xd8\xff\xc0\x00\x01") is None  # segment length under 2
    assert image_header_size(b"\xff\xd8\x12\x34") is None  # no marker where one must be


@settings(max_examples=200, deadline=None)
@given(ext=st.sampled_from([".png", ".jpg"]), cut=st.integers(0, 2000))
def test_a_truncated_header_gives_none_or_the_true_size(ext: str, cut: int) -> None:
    data = _encoded(ext, 23, 17)
    assert image_header_size(data[:cut]) in (None, (23, 17))


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


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([b"\x89PNG\r\n\x1a\n", b"\xff\xd8", b""]), st.binary(max_size=64))
def test_random_bytes_never_raise(prefix: bytes, rest: bytes) -> None:
    size = image_header_size(prefix + rest)
    assert size is None or (size[0] > 0 and size[1] > 0)
