"""The pieces that drive a service in the stress tools and the tests."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from tools.rig import marker_frame, percentile, proc_sample, raw_attachment
from zenoh_perception.wire.frames import decode_attachment


@pytest.mark.parametrize("clutter", [False, True])
def test_a_marker_frame_shows_its_tag_where_it_says(clutter: bool) -> None:
    frame = marker_frame(640, 480, 9, side=100, origin=(200, 150), clutter=clutter, seed=1)
    image = np.frombuffer(frame.payload, np.uint8).reshape(480, 640, 4)
    gray = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = detector.detectMarkers(gray)
    assert ids is not None
    assert 9 in ids.ravel().tolist()
    quad = corners[ids.ravel().tolist().index(9)].reshape(4, 2)
    assert np.abs(quad.mean(axis=0) - frame.center).max() < 0.5


def test_a_marker_that_does_not_fit_is_refused() -> None:
    with pytest.raises(ValueError, match="does not fit"):
        marker_frame(640, 480, 1, side=400, origin=(300, 100))


def test_a_raw_attachment_decodes_to_its_frame() -> None:
    meta = decode_attachment(raw_attachment(320, 240, seq=7, encoding="bgr8"))
    assert (meta.width, meta.height, meta.encoding, meta.seq) == (320, 240, "bgr8", 7)


def test_percentile_of_nothing_is_zero() -> None:
    assert percentile([], 99) == 0.0
    assert percentile([1.0, 2.0, 3.0], 50) == 2.0


def test_proc_sample_reads_this_process() -> None:
    sample = proc_sample(os.getpid())
    assert sample.rss_kib > 0
