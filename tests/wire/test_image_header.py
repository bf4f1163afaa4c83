"""The size an image file declares, read from its header without decoding it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.wire.image_header import image_header_size


@pytest.mark.parametrize("extension", [".png", ".jpg"])
@pytest.mark.parametrize(("width", "height"), [(1, 1), (640, 480), (33, 1000)])
def test_the_declared_size_is_the_encoded_one(extension: str, width: int, height: int) -> None:
    ok, encoded = cv2.imencode(extension, np.zeros((height, width, 3), dtype=np.uint8))
    assert ok
    assert image_header_size(encoded.tobytes()) == (width, height)


def test_a_png_header_is_read_whatever_follows() -> None:
    _ok, encoded = cv2.imencode(".png", np.zeros((2, 2, 3), dtype=np.uint8))
    header = bytearray(encoded.tobytes()[:33])
    header[16:24] = (16000).to_bytes(4, "big") * 2
    assert image_header_size(bytes(header)) == (16000, 16000)


@given(st.binary(max_size=64))
def test_any_bytes_give_a_size_or_none(data: bytes) -> None:
    size = image_header_size(data)
    assert size is None or all(0 <= side < 2**32 for side in size)


@given(st.binary(max_size=64))
def test_any_bytes_after_a_jpeg_start_give_a_size_or_none(data: bytes) -> None:
    size = image_header_size(b"\xff\xd8" + data)
    assert size is None or all(0 <= side < 2**16 for side in size)
