"""A hand-written little-endian CDR writer: golden bytes for message layouts, written from the
.msg definitions alone (rosbags itself is what the tests compare with)."""

from __future__ import annotations

import struct


class CdrWriter:
    """Plain CDR (XCDR1) little endian; alignment counts from after the 4-byte header."""

    def __init__(self) -> None:
        self._body = bytearray()

    def _align(self, size: int) -> None:
        self._body += bytes(-len(self._body) % size)

    def put(self, fmt: str, *values: float) -> CdrWriter:
        size = struct.calcsize("<" + fmt[-1])
        self._align(size)
        self._body += struct.pack("<" + fmt, *values)
        return self

    def string(self, text: str) -> CdrWriter:
        data = text.encode() + b"\x00"
        self.put("I", len(data))
        self._body += data
        return self

    def header(self, sec: int, nanosec: int, frame_id: str) -> CdrWriter:
        return self.put("i", sec).put("I", nanosec).string(frame_id)

    def bytes(self) -> bytes:
        return b"\x00\x01\x00\x00" + bytes(self._body)
