"""The frames of a manifest's items (:mod:`~zenoh_perception_bench.manifest`) as the BGRA
images a camera delivers, one at a time, each refused before it is decoded when larger than
the service would take."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.settings import Settings
from zenoh_perception.wire.image_header import image_header_size
from zenoh_perception_bench.manifest import DatasetError, Item, TooLargeError

Image = npt.NDArray[np.uint8]


def data_folder(manifest: Path, data: Path | None) -> Path:
    """Where the items' files are: ``data`` if given, else ``data/`` beside the manifest if
    there is one, else the manifest's own folder (what ``--init`` writes for).

    Raises:
        DatasetError: that folder does not exist.

    """
    folder = data
    if folder is None:
        beside = manifest.parent / "data"
        folder = beside if beside.is_dir() else manifest.parent
    if not folder.is_dir():
        msg = f"data folder {folder} does not exist (pass --data FOLDER: your pictures' folder)"
        raise DatasetError(msg)
    return folder


def _file(data: Path, item: Item) -> Path:
    # exact names, not a glob: a name is the user's text, not a pattern
    try:
        found = sorted(p for p in data.iterdir() if p.stem == item.name and p.is_file())
    except OSError as err:
        msg = f"item {item.name}: cannot list {data}: {err.strerror}"
        raise DatasetError(msg) from err
    if not found:
        msg = (
            f"item {item.name}: no file {item.name}.<ext> in {data} (put the picture there,"
            " or pass --data with the folder that holds it)"
        )
        raise DatasetError(msg)
    return found[0]


def _bgra(image: Any) -> Image:
    if image.ndim == 2:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGRA), dtype=np.uint8)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2BGRA), dtype=np.uint8)


def _too_large(path: Path, width: int, height: int, max_pixels: int) -> TooLargeError:
    return TooLargeError(
        f"{path}: {width}x{height} = {width * height} pixels, more than max_frame_pixels ="
        f" {max_pixels} (raise it with --settings to bench this picture)"
    )


def _read_image(path: Path, max_pixels: int) -> Image:
    """A picture as BGRA, refused before it is decoded when its header declares more than
    ``max_pixels`` pixels (PNG and JPEG; other formats once decoded)."""
    try:
        size = path.stat().st_size
        # no picture of max_pixels needs more than 8 bytes a pixel (16-bit RGBA, stored)
        if size > 8 * max_pixels + (1 << 20):
            msg = f"{path}: {size} bytes, too large for max_frame_pixels = {max_pixels}"
            raise TooLargeError(msg)
        data = path.read_bytes()
    except OSError as err:
        msg = f"cannot read image {path}: {err.strerror}"
        raise DatasetError(msg) from err
    declared = image_header_size(data)
    if declared is not None and declared[0] * declared[1] > max_pixels:
        raise _too_large(path, *declared, max_pixels)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        msg = f"cannot read image {path}"
        raise DatasetError(msg)
    if image.shape[0] * image.shape[1] > max_pixels:
        raise _too_large(path, image.shape[1], image.shape[0], max_pixels)
    return _bgra(image)


DEFAULT_MAX_PIXELS: Final = Settings().limits.max_frame_pixels


def frames(
    item: Item, data: Path, max_frames: int, max_pixels: int = DEFAULT_MAX_PIXELS
) -> Iterator[Image]:
    """The item's frames as BGRA images, one at a time (a video: at most ``max_frames``),
    flipped back left to right when the item was stored mirrored.

    Raises:
        DatasetError: missing or unreadable file, or a frame of more than ``max_pixels``.

    """
    for image in _stored_frames(item, data, max_frames, max_pixels):
        yield np.asarray(cv2.flip(image, 1), np.uint8) if item.mirrored else image


def _stored_frames(item: Item, data: Path, max_frames: int, max_pixels: int) -> Iterator[Image]:
    if item.kind == "sequence":
        folder = data / item.name
        paths = sorted(p for p in folder.iterdir() if p.is_file()) if folder.is_dir() else []
        if not paths:
            msg = f"item {item.name}: no frames in {folder} (a sequence is a folder of pictures)"
            raise DatasetError(msg)
        for path in paths[:max_frames]:
            yield _read_image(path, max_pixels)
        return
    path = _file(data, item)
    if item.kind == "image":
        yield _read_image(path, max_pixels)
        return
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        msg = f"cannot open video {path}"
        raise DatasetError(msg)
    try:
        width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if width * height > max_pixels:
            raise _too_large(path, width, height, max_pixels)
        count = 0
        while count < max_frames:
            ok, image = capture.read()
            if not ok:
                break
            if image.shape[0] * image.shape[1] > max_pixels:
                raise _too_large(path, image.shape[1], image.shape[0], max_pixels)
            count += 1
            yield _bgra(image)
    finally:
        capture.release()
    if count == 0:
        msg = f"video {path} has no frame OpenCV can read"
        raise DatasetError(msg)
