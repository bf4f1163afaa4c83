"""What every detector returns and accepts, and the names settings may use. Imports no OpenCV."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum, StrEnum
from typing import Final, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from zenoh_perception.errors import SettingsError

R = TypeVar("R")

#: OpenCV's predefined ArUco and AprilTag dictionaries (``cv2.aruco.DICT_*``).
DICTIONARIES: Final = (
    "DICT_4X4_50",
    "DICT_4X4_100",
    "DICT_4X4_250",
    "DICT_4X4_1000",
    "DICT_5X5_50",
    "DICT_5X5_100",
    "DICT_5X5_250",
    "DICT_5X5_1000",
    "DICT_6X6_50",
    "DICT_6X6_100",
    "DICT_6X6_250",
    "DICT_6X6_1000",
    "DICT_7X7_50",
    "DICT_7X7_100",
    "DICT_7X7_250",
    "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11",
    "DICT_ARUCO_MIP_36h12",
)


class DetectorKind(StrEnum):
    """The detectors settings may name: ``opencv`` (the default), OpenCV's detector on every
    whole frame; ``tracking``, the same detector on whole frames when needed, on regions
    around known tags in between."""

    OPENCV = "opencv"
    TRACKING = "tracking"


#: Every detector's name, as the settings write it.
DETECTORS: Final = tuple(DetectorKind)


def dictionary_name(name: str) -> str:
    """The canonical spelling of dictionary ``name`` (case-insensitive).

    Raises:
        SettingsError: ``name`` is not one of :data:`DICTIONARIES`.

    """
    for known in DICTIONARIES:
        if known.upper() == name.upper():
            return known
    msg = f"unknown ArUco dictionary {name!r}; choose one of {', '.join(DICTIONARIES)}"
    raise SettingsError(msg)


def dictionary_names(names: str) -> tuple[str, ...]:
    """The dictionaries of a ``dictionary`` setting: one name, or several separated by commas
    (``"DICT_4X4_50, DICT_APRILTAG_16h5"``), each in its canonical spelling, without repeats.

    Raises:
        SettingsError: an unknown name, or none at all.

    """
    found: list[str] = []
    for part in names.split(","):
        name = dictionary_name(part.strip())
        if name not in found:
            found.append(name)
    return tuple(found)


@dataclass(frozen=True, slots=True)
class Detection:
    """One decoded marker: id, its four corners (float32, shape (4, 2)) and the dictionary it
    was decoded in ("" where the detector does not say).

    Corner order is OpenCV's: top-left, top-right, bottom-right, bottom-left of the marker.
    """

    tag_id: int
    corners: npt.NDArray[np.float32]
    dictionary: str = ""


class Detector(Protocol):
    """Anything that finds markers in a grey (single-channel uint8) image.

    A detector may keep state between calls (a stream's previous frames): use one per stream.
    Besides :meth:`detect` it says what else it can do, each with a default for a detector
    that cannot (subclass this protocol to take them): a read of the frame left until after
    its tag is out (:meth:`look_again`), an array to convert the next frame into
    (:meth:`gray_buffer`), and another read of the frame under its deadline
    (:meth:`watched`).
    """

    def detect(self, gray: npt.NDArray[np.uint8]) -> list[Detection]:
        """Return every marker found in ``gray``."""
        ...

    def look_again(self) -> list[Detection]:
        """What a read left until after the frame's tag adds to the frame :meth:`detect` read
        last (the second look, :mod:`~zenoh_perception.detect.second_look`); once per frame,
        after :meth:`detect`. None left: []."""
        return []

    def gray_buffer(self, height: int, width: int) -> npt.NDArray[np.uint8] | None:
        """Where the next frame's grey image goes, so that it is not copied again (a child
        process's shared segment); None: any array."""
        return None

    def watched(self, read: Callable[[], R]) -> R | None:
        """``read()``, a read of the frame besides this detector's own (the coarse first read,
        :mod:`~zenoh_perception.detect.coarse`), under whatever deadline bounds
        :meth:`detect`; None where that deadline cannot bound it (the read is not taken).
        Without a deadline: ``read()``."""
        return read()


class Due(Enum):
    """When a frame gets its second look: before its tag is chosen, or after it is out."""

    NOW = "now"
    LATER = "later"


class Looker(Protocol):
    """A second read of a frame after the detector's (see
    :class:`~zenoh_perception.detect.second_look.SecondLook`)."""

    def due(self, shape: tuple[int, ...], found: Sequence[Detection]) -> Due | None:
        """When the frame of ``shape`` whose first read found ``found`` is read again
        (:class:`Due`), or None."""
        ...

    def look(
        self,
        image: npt.NDArray[np.uint8],
        found: list[Detection],
        keep: Callable[[npt.NDArray[np.float32]], bool],
        rejected: Sequence[npt.NDArray[np.float32]],
    ) -> list[Detection]:
        """``found`` and what the second read adds to it (markers ``keep`` accepts), given
        the candidates the first read ``rejected`` (OpenCV's quads)."""
        ...
