"""Periodic grids beside tags: checkerboards (straight, rotated, in perspective) and a tiled
floor over part of a frame, with markers on the rest (pure: numpy + cv2 only).

A board of squares just above OpenCV's smallest marker gives its ``ArucoDetector`` thousands
of candidate quads; these frames measure and test what the detector does beside one.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._raster import render_markers

#: The kinds of board: squares along the frame's axes, turned, seen in perspective, and a
#: floor of light and dark tiles with grout lines receding to the horizon.
BOARD_KINDS = ("straight", "rotated", "perspective", "floor")


@dataclass(frozen=True)
class BoardScene:
    """A BGRA frame, the markers on it as ``(id, corners (4, 2))`` and the board's pixels."""

    image: npt.NDArray[np.uint8]
    markers: tuple[tuple[int, npt.NDArray[np.float32]], ...]
    board: npt.NDArray[np.bool_]


def _square(left: float, top: float, side: float) -> npt.NDArray[np.float32]:
    """The corners of an upright square tag, OpenCV's order (top-left first, clockwise)."""
    return np.array(
        [[left, top], [left + side, top], [left + side, top + side], [left, top + side]],
        np.float32,
    )


def board_texture(
    width: int, height: int, square: float, kind: str, seed: int = 0
) -> npt.NDArray[np.uint8]:
    """A ``width`` x ``height`` grey picture filled with a board of ``kind`` whose squares are
    about ``square`` pixels (in perspective: that size in the middle of the picture)."""
    rng = np.random.default_rng(seed)
    y, x = np.indices((height, width), dtype=np.float32)
    if kind == "straight":
        u, v = x / square, y / square
    elif kind == "rotated":
        angle = np.deg2rad(rng.uniform(15.0, 75.0))
        u = (x * np.cos(angle) + y * np.sin(angle)) / square
        v = (-x * np.sin(angle) + y * np.cos(angle)) / square
    elif kind == "perspective":
        # a board tilted away: rows further up are further away, squares shrink towards them
        tilt = rng.uniform(0.5, 0.9)
        depth = 1.0 + tilt * (0.5 - y / height)
        u = (x - width / 2) / depth / square
        v = (y / depth) / square
    elif kind == "floor":
        # a floor seen from above its horizon (above the picture): rows further down are
        # nearer, tiles grow and are foreshortened less; ``square`` wide in the middle row
        horizon = -rng.uniform(0.2, 0.5) * height
        near = (y - horizon) / (height / 2 - horizon)  # 1 in the middle row
        u = (x - width / 2) / (square * near)
        v = (height / 2 - horizon) / (0.6 * square * near)
    else:
        msg = f"unknown board kind {kind!r}"
        raise ValueError(msg)
    # supersample-free anti-aliasing: the square wave smoothed over about a pixel
    if kind == "floor":
        tiles = (np.floor(u) + np.floor(v)) % 2
        light = np.where(tiles > 0, 200.0, 120.0)
        grout = (np.minimum(u % 1, v % 1) < 0.08) | (np.maximum(u % 1, v % 1) > 0.92)
        grey = np.where(grout, 60.0, light)
    else:
        grey = ((np.floor(u) + np.floor(v)) % 2) * 235.0 + 10.0
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (3, 3), 0.6)
    return np.asarray(np.clip(smooth, 0, 255), np.uint8)


def board_scene(
    width: int,
    height: int,
    square: float,
    kind: str,
    *,
    tags: tuple[int, ...] = (3, 7),
    tag_side: int = 80,
    seed: int = 0,
    dictionary: str = "DICT_4X4_50",
) -> BoardScene:
    """A board of ``kind`` over the left half of the frame and ``tags`` in a column beside it
    on a light background (each ``tag_side`` px, its quiet zone clear of the board)."""
    half = width // 2
    background = np.full((height, width), 205, np.uint8)
    background[:, :half] = board_texture(half, height, square, kind, seed)
    board = np.zeros((height, width), bool)
    board[:, :half] = True
    markers = []
    gap = height // (len(tags) + 1)
    for index, tag_id in enumerate(tags):
        left = float(half + tag_side // 2 + 40 * index)
        top = float(gap * (index + 1) - tag_side // 2)
        markers.append((tag_id, _square(left, top, tag_side)))
    image = render_markers(width, height, markers, dictionary=dictionary, background=background)
    return BoardScene(image, tuple(markers), board)


def busy_board_scene(
    width: int = 1280,
    height: int = 720,
    *,
    square: float = 10.0,
    share: float = 0.8,
    tags: tuple[int, ...] = (3, 7),
    dictionary: str = "DICT_4X4_50",
) -> BoardScene:
    """A straight board of ``square`` px over the left ``share`` of the frame and ``tags`` in a
    column on the light strip beside it: at HD720, 10 px and 0.8, OpenCV's default takes over
    a second a frame, past any frame deadline."""
    edge = int(width * share)
    background = np.full((height, width), 205, np.uint8)
    background[:, :edge] = board_texture(edge, height, square, "straight")
    board = np.zeros((height, width), bool)
    board[:, :edge] = True
    side = max(24, min(width - edge - 40, height // (2 * len(tags))))
    gap = height // len(tags)
    markers = []
    for index, tag_id in enumerate(tags):
        left, top = float(edge + 20), float(gap * index + (gap - side) // 2)
        markers.append((tag_id, _square(left, top, side)))
    image = render_markers(width, height, markers, dictionary=dictionary, background=background)
    return BoardScene(image, tuple(markers), board)
