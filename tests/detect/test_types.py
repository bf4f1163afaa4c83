"""Dictionary and detector names as the settings give them; no OpenCV needed to check them."""

from __future__ import annotations

import cv2
import pytest

from zenoh_perception.detect.types import DETECTORS, DICTIONARIES, dictionary_name
from zenoh_perception.errors import SettingsError


@pytest.mark.parametrize("name", ["DICT_4X4_50", "dict_4x4_50", "Dict_AprilTag_36H11"])
def test_dictionary_names_are_case_insensitive_and_canonical(name: str) -> None:
    assert dictionary_name(name) in DICTIONARIES
    assert dictionary_name(name).upper() == name.upper()


@pytest.mark.parametrize("name", ["DICT_9X9_1", "", "4X4_50", "DICT_4X4_50 "])
def test_unknown_dictionaries_are_settings_errors(name: str) -> None:
    with pytest.raises(SettingsError, match="unknown ArUco dictionary"):
        dictionary_name(name)


def test_every_dictionary_is_one_opencv_predefines() -> None:
    ids = {getattr(cv2.aruco, name) for name in DICTIONARIES}
    assert len(ids) == len(DICTIONARIES) == len(set(DICTIONARIES))
    for name in DICTIONARIES:
        assert cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0] > 0


def test_the_default_detector_comes_first() -> None:
    assert DETECTORS[0] == "opencv"
    assert len(set(DETECTORS)) == len(DETECTORS)
