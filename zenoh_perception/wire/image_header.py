"""The size an image file declares in its header, read without decoding it.

A 249 KB PNG can declare 16000 x 16000 pixels, which a decoder allocates (about 1 GB, 2.8 GB
with the conversions) before anything can refuse it. The declared size is read first: PNG's
IHDR, JPEG's SOFn segment. Pure; no OpenCV.
"""

from __future__ import annotations

import struct
from typing import Final

_PNG_SIGNATURE: Final = b"\x89PNG\r\n\x1a\n"
# SOF0..SOF15 carry the frame size, except DHT (C4), JPG (C8) and DAC (CC)
_JPEG_SOF: Final = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# markers without a length: TEM, RST0..7 (SOI and EOI are handled apart)
_JPEG_STANDALONE: Final = frozenset({0x01, *range(0xD0, 0xD8)})


def image_header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) that a PNG or JPEG file's header declares; None for another format or
    a header too short or malformed to tell."""
    if data.startswith(_PNG_SIGNATURE):
        return _png_size(data)
    if data.startswith(b"\xff\xd8"):
        return _jpeg_size(data)
    return None


def _png_size(data: bytes) -> tuple[int, int] | None:
    # signature, then the IHDR chunk first: length (4), type (4), width (4), height (4)
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    index = 2
    while index + 4 <= len(data):
        if data[index] != 0xFF:
            return None
        marker = data[index + 1]
        if marker == 0xFF:  # fill byte
            index += 1
            continue
        if marker in _JPEG_STANDALONE:
            index += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image, or start of scan before any frame header
            return None
        (length,) = struct.unpack(">H", data[index + 2 : index + 4])
        if length < 2:
            return None
        if marker in _JPEG_SOF:
            # length (2), precision (1), height (2), width (2)
            if index + 9 > len(data):
                return None
            height, width = struct.unpack(">HH", data[index + 5 : index + 9])
            return int(width), int(height)
        index += 2 + length
    return None
