"""The picture size a PNG or JPEG file declares in its header, read without decoding it.

A decoder allocates what the header declares: a 249 KB PNG can declare 16000 x 16000 pixels
and make OpenCV allocate gigabytes. Reading the declared size first lets a caller refuse such
a picture before any pixel is decoded. The reader only looks at the bytes it is given and
never allocates from a size they declare.
"""

from __future__ import annotations

from typing import Final

PNG_SIGNATURE: Final = b"\x89PNG\r\n\x1a\n"
#: PNG widths and heights are at most 2**31 - 1.
_PNG_MAX: Final = 2**31 - 1
#: JPEG start-of-frame markers (SOF0..SOF15 but DHT C4, JPG C8 and DAC CC).
_JPEG_SOF: Final = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: JPEG markers that stand alone, with no length after them (TEM, RST0..7, SOI).
_JPEG_STANDALONE: Final = frozenset({0x01, *range(0xD0, 0xD8), 0xD8})


def image_header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) that the PNG or JPEG in ``data`` declares, as stored (before any EXIF
    rotation); None when ``data`` is neither, or its header is truncated or corrupt."""
    if data.startswith(PNG_SIGNATURE):
        return _png(data)
    if data.startswith(b"\xff\xd8"):
        return _jpeg(data)
    return None


def _png(data: bytes) -> tuple[int, int] | None:
    # the first chunk must be IHDR: length 13, then width and height, big-endian
    header = data[8:24]
    if len(header) < 16 or header[:8] != b"\x00\x00\x00\x0dIHDR":
        return None
    width = int.from_bytes(header[8:12], "big")
    height = int.from_bytes(header[12:16], "big")
    if not (0 < width <= _PNG_MAX and 0 < height <= _PNG_MAX):
        return None
    return width, height


def _jpeg(data: bytes) -> tuple[int, int] | None:
    pos = 2
    end = len(data)
    while pos < end:
        if data[pos] != 0xFF:
            return None
        while pos < end and data[pos] == 0xFF:  # fill bytes before a marker
            pos += 1
        if pos >= end:
            return None
        marker = data[pos]
        pos += 1
        if marker in _JPEG_STANDALONE:
            continue
        if marker in (0xD9, 0xDA, 0x00):  # end of image or scan data before any frame header
            return None
        if pos + 2 > end:
            return None
        length = int.from_bytes(data[pos : pos + 2], "big")
        if length < 2:
            return None
        if marker in _JPEG_SOF:
            # precision (1 byte), height, width (2 bytes each)
            if length < 7 or pos + 7 > end:
                return None
            height = int.from_bytes(data[pos + 3 : pos + 5], "big")
            width = int.from_bytes(data[pos + 5 : pos + 7], "big")
            # a height of 0 is defined later (DNL marker): the size is not known from here
            return (width, height) if width > 0 and height > 0 else None
        pos += length
    return None
