"""OpenCV's ArUco detector with its default parameters: whole frames, and regions of a frame
(at full or reduced scale) read as the whole frame would be."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.detect.opencv import (
    OpenCvDetector,
    aruco_dictionary,
    detections_from_opencv,
)
from zenoh_perception.errors import SettingsError
from zenoh_perception_bench.scene import render_markers

W, H = 640, 480


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _gray(image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    return np.ascontiguousarray(image[:, :, 1])  # rendered tags are grey: any channel


FRAME = _gray(render_markers(W, H, [(3, _square(100, 100, 80)), (7, _square(400, 250, 120))]))


def test_every_marker_is_found_with_its_corners() -> None:
    found = {d.tag_id: d.corners for d in OpenCvDetector("DICT_4X4_50").detect(FRAME)}
    assert sorted(found) == [3, 7]
    for tag_id, quad in [(3, _square(100, 100, 80)), (7, _square(400, 250, 120))]:
        assert found[tag_id].dtype == np.float32 and found[tag_id].shape == (4, 2)
        # corners in OpenCV's order (top-left first, clockwise), without sub-pixel refinement
        # within a pixel and a half of the truth; their mean (the centre) far closer
        assert np.abs(found[tag_id] - quad).max() < 1.5
        assert np.abs(found[tag_id].mean(axis=0) - quad.mean(axis=0)).max() < 0.5


def test_nothing_is_found_in_an_empty_frame_or_with_another_dictionary() -> None:
    assert OpenCvDetector("DICT_4X4_50").detect(_gray(render_markers(W, H, []))) == []
    assert OpenCvDetector("DICT_6X6_250").detect(FRAME) == []


def test_a_region_is_read_in_the_frame_s_coordinates() -> None:
    detector = OpenCvDetector("DICT_4X4_50")
    whole = {d.tag_id: d.corners for d in detector.detect(FRAME)}
    x0, y0 = 360, 210
    region = np.ascontiguousarray(FRAME[y0:, x0:])
    (found,) = detector.detect_region(region, (x0, y0))
    assert found.tag_id == 7
    np.testing.assert_allclose(found.corners, whole[7], atol=1e-4)


@pytest.mark.parametrize("scale", [2, 4])
def test_a_region_read_at_a_smaller_scale_keeps_full_resolution_corners(scale: int) -> None:
    detector = OpenCvDetector("DICT_4X4_50")
    frame = _gray(render_markers(W, H, [(8, _square(150, 80, 300))]))
    region = np.ascontiguousarray(frame[40:440, 100:500])
    (found,) = detector.detect_region(region, (100, 40), scale=scale)
    assert found.tag_id == 8
    assert np.abs(found.corners - _square(150, 80, 300)).max() < 1.0


def test_a_colour_region_is_read_too() -> None:
    detector = OpenCvDetector("DICT_4X4_50")
    bgr = cv2.cvtColor(FRAME, cv2.COLOR_GRAY2BGR)
    (found,) = detector.detect_region(np.ascontiguousarray(bgr[200:, 350:]), (350, 200), scale=2)
    assert found.tag_id == 7
    assert np.abs(found.corners - _square(400, 250, 120)).max() < 1.0


def test_a_region_keeps_the_whole_frame_s_smallest_marker() -> None:
    # OpenCV's smallest marker perimeter is 3 % of the image's larger side: 120 px on a frame
    # 4,000 px wide, so a whole-frame read skips a 28 px marker (perimeter 112 px)
    frame = _gray(render_markers(4000, 200, [(5, _square(2000, 60, 28))]))
    detector = OpenCvDetector("DICT_4X4_50")
    assert detector.detect(frame) == []
    region = np.ascontiguousarray(frame[20:140, 1960:2080])
    assert detector.detect_region(region, (1960, 20), frame_side=4000) == []
    # a region read on its own terms finds it, and whole frames still use OpenCV's own rate
    (found,) = detector.detect_region(region, (1960, 20))
    assert found.tag_id == 5
    assert detector.detect(frame) == []
    wide = _gray(render_markers(1000, 200, [(5, _square(500, 60, 28))]))
    assert [d.tag_id for d in detector.detect(wide)] == [5]


def test_a_smallest_perimeter_skips_smaller_markers_only() -> None:
    # markers of 40 px (perimeter 160 px) and 120 px (480 px) on one frame
    frame = _gray(render_markers(W, H, [(3, _square(60, 60, 40)), (7, _square(300, 200, 120))]))
    detector = OpenCvDetector("DICT_4X4_50")
    assert sorted(d.tag_id for d in detector.detect(frame, min_perimeter_px=150)) == [3, 7]
    assert [d.tag_id for d in detector.detect(frame, min_perimeter_px=200)] == [7]
    assert detector.detect(frame, min_perimeter_px=500) == []
    # in full-resolution pixels whatever the scale a region is read at
    region = np.ascontiguousarray(frame[20:360, 20:460])
    assert [d.tag_id for d in detector.detect_region(region, (20, 20), 2, 0, 200)] == [7]
    assert sorted(d.tag_id for d in detector.detect_region(region, (20, 20), 2, 0, 150)) == [3, 7]
    # and the floor is for that read only
    assert sorted(d.tag_id for d in detector.detect(frame)) == [3, 7]


def test_opencv_output_becomes_detections_shifted_by_the_offset() -> None:
    quad = np.array([[[1.0, 2.0], [3.0, 2.0], [3.0, 4.0], [1.0, 4.0]]], dtype=np.float32)
    (detection,) = detections_from_opencv([quad], np.array([[9]]), offset=(10, 20))
    assert detection.tag_id == 9
    np.testing.assert_array_equal(detection.corners, quad[0] + (10, 20))
    assert detections_from_opencv([], None) == []
    assert detections_from_opencv([], np.zeros((0, 1))) == []


def test_unknown_dictionaries_are_settings_errors() -> None:
    with pytest.raises(SettingsError):
        aruco_dictionary("DICT_9X9_1")
    with pytest.raises(SettingsError):
        OpenCvDetector("DICT_9X9_1")
    assert aruco_dictionary("dict_4x4_50").bytesList.shape[0] == 50


def _two_families() -> npt.NDArray[np.uint8]:
    left = render_markers(W, H, [(7, _square(60, 60, 150))])
    right = render_markers(W, H, [(23, _square(380, 200, 150))], dictionary="DICT_APRILTAG_16h5")
    return np.minimum(_gray(left), _gray(right))


def test_several_dictionaries_are_read_in_one_pass_each_detection_naming_its_own() -> None:
    image = _two_families()
    both = OpenCvDetector("dict_4x4_50, DICT_APRILTAG_16h5")
    assert both.dictionaries == ("DICT_4X4_50", "DICT_APRILTAG_16h5")
    found = sorted((d.tag_id, d.dictionary) for d in both.detect(image))
    assert found == [(7, "DICT_4X4_50"), (23, "DICT_APRILTAG_16h5")]
    # one dictionary reads its own marker only, and names it too
    (only,) = OpenCvDetector("DICT_APRILTAG_16h5").detect(image)
    assert (only.tag_id, only.dictionary) == (23, "DICT_APRILTAG_16h5")
    # regions read every dictionary as well, at full and reduced scale
    for scale in (1, 2):
        region = both.detect_region(image[150:400, 330:580], (330, 150), scale=scale)
        assert [(d.tag_id, d.dictionary) for d in region] == [(23, "DICT_APRILTAG_16h5")]


def test_a_dictionary_list_with_an_unknown_name_is_a_settings_error() -> None:
    with pytest.raises(SettingsError, match="DICT_9X9"):
        OpenCvDetector("DICT_4X4_50, DICT_9X9")
