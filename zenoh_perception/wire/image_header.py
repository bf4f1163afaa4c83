"""The size a compressed image declares, read from its header without decoding it.

A few hundred bytes of PNG or JPEG can declare an image of gigabytes: the service reads the
declared width and height here and refuses an image over ``max_frame_pixels`` before OpenCV
allocates anything for it.

- PNG: the 8-byte signature, then the IHDR chunk (always first) holds width and height as
  big-endian uint32.
- JPEG: SOI, then marker segments up to the first start-of-frame (SOF0-SOF15 except DHT
  ``C4``, JPG ``C8`` and DAC ``CC``, which share the range), whose payload is precision (1
  byte), height and width (big-endian uint16).

Pure: no OpenCV, no allocation beyond the integers read.
"""

from __future__ import annotations

from typing import Final

PNG_SIGNATURE: Final = b"\x89PNG\r\n\x1a\n"
JPEG_SOI: Final = b"\xff\xd8"
#: PNG widths and heights are at most 2**31 - 1 (its specification).
_PNG_MAX_SIDE: Final = 2**31 - 1

#: SOFn markers: C0..CF but for DHT (C4), JPG (C8) and DAC (CC).
_SOF_MARKERS: Final = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: Markers without a length field (TEM, RST0-RST7); SOI again would be a corrupt stream.
_STANDALONE: Final = frozenset({0x01, *range(0xD0, 0xD8)})
#: Markers after which no SOF can come before image data: EOI, SOS, SOI.
_NO_SOF_AFTER: Final = frozenset({0xD9, 0xDA, 0xD8})


def image_header_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` declared by a PNG or JPEG header; None when ``data`` is neither,
    is cut before the size, or declares a zero side (a JPEG whose height comes later, in a
    DNL segment, included)."""
    if data.startswith(PNG_SIGNATURE):
        return _png_size(data)
    if data.startswith(JPEG_SOI):
        return _jpeg_size(data)
    return None


def _png_size(data: bytes) -> tuple[int, int] | None:
    # signature (8), chunk length (4), b"IHDR" (4), width (4), height (4)
    if len(data) < 24 or data[8:16] != b"\x00\x00\x00\x0dIHDR":
        return None
    width = int.from_bytes(data[16:20], "big")
    height = int.from_bytes(data[20:24], "big")
    if not (0 < width <= _PNG_MAX_SIDE and 0 < height <= _PNG_MAX_SIDE):
        return None
    return width, height


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    pos = len(JPEG_SOI)
    end = len(data)
    while pos < end:
        if data[pos] != 0xFF:
            return None  # a segment must start with a marker
        # any number of 0xFF fill bytes may precede the marker code
        while pos < end and data[pos] == 0xFF:
            pos += 1
        if pos >= end:
            return None
        marker = data[pos]
        pos += 1
        if marker in _STANDALONE:
            continue
        if marker in _NO_SOF_AFTER or marker == 0x00:
            return None
        if pos + 2 > end:
            return None
        length = int.from_bytes(data[pos : pos + 2], "big")  # counts itself, not the marker
        if length < 2:
            return None
        if marker in _SOF_MARKERS:
            # length (2), precision (1), height (2), width (2)
            if length < 7 or pos + 7 > end:
                return None
            height = int.from_bytes(data[pos + 3 : pos + 5], "big")
            width = int.from_bytes(data[pos + 5 : pos + 7], "big")
            if width == 0 or height == 0:
                return None
            return width, height
        pos += length
    return None
