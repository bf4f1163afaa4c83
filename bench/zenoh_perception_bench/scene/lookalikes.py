"""Frames of things that are not markers of a dictionary but that OpenCV's default ArUco
detector may read as one (pure: numpy + cv2 only).

Each kind is drawn the way such a thing looks to a camera, with a code of the dictionary
hidden in it where a real look-alike happens to hold one (the detector decodes nothing else):

- ``keys``: a keyboard: dark key-caps on a dark base, each with a light glyph; the glyph of
  some caps joins the white cells of a code (a letter that happens to read as an id);
- ``text``: book spines: dark bands with light lettering, one letter of a band a code;
- ``tiles``: a tiled surface: dark glazed tiles with a light pattern (soft blobs or crisp
  strokes that join the white cells of a code), dark joints between them;
- ``other_family``: markers of families whose grid has another number of cells, printed with
  their quiet zone, 24 px a side or more (a family of the same grid size reads the same cells
  as the dictionary: only the codes tell them apart, and OpenCV has read those; and under
  about 24 px a cell has too few pixels to tell one grid size from another);
- ``pictograms``: handling pictograms printed on cardboard boxes, 14-34 px: a white symbol in
  a dark square (ISO 780 "this way up": two arrows and a bar; "keep dry": an umbrella;
  "fragile": a glass; "do not stack": two boxes crossed out), whose strokes OpenCV reads as
  the white cells of a 4 x 4 code (no code is hidden: the symbols themselves read as ids).

:func:`lookalike_frame` draws one frame of a kind; :func:`true_tag_frame` draws true markers
of the dictionary, small, blurred, oblique, in shadow and JPEG'd, on a light ground, the
markers a veto must never reject.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._camera_effects import jpeg
from zenoh_perception_bench.scene._distractors import render_distractor
from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._raster import (
    aruco_dictionary,
    canvas_from,
    homography,
    marker_patch,
    paste,
    patch_outline,
    to_bgra,
    u8,
)

Image = npt.NDArray[np.uint8]

#: Every look-alike kind.
LOOKALIKE_KINDS: Final = ("keys", "text", "tiles", "other_family")
#: Every kind :func:`lookalike_frame` draws. ``pictograms`` is not among the bench's kinds: the
#: veto removes about 98 in 100 of the ids OpenCV reads on them, not all (a glass or a pair of
#: arrows at 14-17 px, blurred, is a clean enough code), and the bench asks for none.
DRAWN_KINDS: Final = (*LOOKALIKE_KINDS, "pictograms")
#: The symbols ``pictograms`` draws.
PICTOGRAMS: Final = ("this_way_up", "keep_dry", "fragile", "do_not_stack")
#: One dictionary of each family: the families ``other_family`` draws from.
FAMILIES: Final = (
    "DICT_4X4_50",
    "DICT_5X5_50",
    "DICT_6X6_50",
    "DICT_7X7_50",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11",
    "DICT_ARUCO_MIP_36h12",
)


def family(dictionary: str) -> str:
    """The family of ``dictionary``: its name without the count (DICT_4X4_250 -> DICT_4X4)."""
    head, _, tail = dictionary.rpartition("_")
    return head if tail.isdigit() and "X" in head else dictionary


@dataclass(frozen=True, slots=True)
class TrueTag:
    """A true marker drawn on a frame: its id and the outer corners of its black border."""

    tag_id: int
    corners: npt.NDArray[np.float64]


def _ids(dictionary: str) -> int:
    return int(aruco_dictionary(dictionary).bytesList.shape[0])


def _skewed(
    x: float, y: float, side: float, rng: np.random.Generator, skew: float
) -> npt.NDArray[np.float64]:
    """A square of ``side`` at (x, y) (top-left), corners moved by up to ``skew`` of its side."""
    quad = np.array([[x, y], [x + side, y], [x + side, y + side], [x, y + side]], np.float64)
    return quad + rng.uniform(-skew, skew, (4, 2)) * side


def _paste_art(
    canvas: Image, art: Image, core: npt.NDArray[np.float64], quad: npt.ArrayLike
) -> None:
    paste(canvas, art, homography(core, np.asarray(quad, np.float64)), pixel_art=False)


def _letter(
    canvas: Image, quad: npt.NDArray[np.float64], level: int, rng: np.random.Generator
) -> None:
    side = float(np.linalg.norm(quad[1] - quad[0]))
    text = "QWERTYUIOPASDFGHJKLZXCVBNM1234567890"[int(rng.integers(36))]
    scale = max(0.2, side / 40.0)
    thick = max(1, round(side / 12.0))
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    cx, cy = quad.mean(axis=0)
    org = (round(cx - tw / 2), round(cy + th / 2))
    colour = (level, level, level)
    cv2.putText(canvas, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


def _keys(dictionary: str, width: int, height: int, rng: np.random.Generator) -> Image:
    base = int(rng.integers(5, 35))
    canvas = canvas_from(width, height, base)
    key = float(rng.uniform(11.0, 40.0))
    gap = max(2.0, key * float(rng.uniform(0.12, 0.3)))
    y = gap
    while y + key < height:
        x = gap + float(rng.uniform(0, key))
        while x + key < width:
            quad = _skewed(x, y, key, rng, 0.02)
            if rng.random() < 0.5:
                art = render_distractor(
                    "glyph",
                    dictionary,
                    int(rng.integers(_ids(dictionary))),
                    side_px=key,
                    ratio=1.0,
                    rng=rng,
                )
                _paste_art(canvas, art.patch, art.core, quad)
            else:
                cap = int(base + rng.integers(5, 30))
                cv2.fillConvexPoly(canvas, np.rint(quad).astype(np.int32), (cap, cap, cap))
                _letter(canvas, quad, int(rng.integers(150, 250)), rng)
            x += key + gap
        y += key + gap
    return canvas


def _text(dictionary: str, width: int, height: int, rng: np.random.Generator) -> Image:
    canvas = canvas_from(width, height, int(rng.integers(120, 200)))
    x = 0.0
    while x < width:
        band = float(rng.uniform(14.0, 45.0))
        level = int(rng.integers(10, 60))
        cv2.rectangle(
            canvas, (round(x), 0), (round(x + band), height - 1), (level, level, level), -1
        )
        letter = band * float(rng.uniform(0.6, 0.8))
        y = float(rng.uniform(5, 40))
        coded = int(rng.integers(3))
        index = 0
        while y + letter < height:
            quad = _skewed(x + (band - letter) / 2, y, letter, rng, 0.01)
            if index == coded:
                art = render_distractor(
                    "bare_code",
                    dictionary,
                    int(rng.integers(_ids(dictionary))),
                    side_px=letter,
                    ratio=1.0,
                    rng=rng,
                )
                _paste_art(canvas, art.patch, art.core, quad)
            else:
                _letter(canvas, quad, int(rng.integers(170, 250)), rng)
            y += letter * 1.3
            index += 1
        x += band + float(rng.uniform(0, 4))
    return canvas


def _tiles(dictionary: str, width: int, height: int, rng: np.random.Generator) -> Image:
    grout = int(rng.integers(0, 16))
    canvas = canvas_from(width, height, grout)
    tile = float(rng.uniform(12.0, 48.0))
    joint = max(1.0, tile * float(rng.uniform(0.05, 0.15)))
    y = joint
    while y < height:
        x = joint
        while x < width:
            quad = _skewed(x, y, tile - joint, rng, 0.01)
            kind = "blob" if rng.random() < 0.5 else "glyph"
            art = render_distractor(
                kind,
                dictionary,
                int(rng.integers(_ids(dictionary))),
                side_px=tile,
                ratio=1.0,
                rng=rng,
            )
            _paste_art(canvas, art.patch, art.core, quad)
            x += tile
        y += tile
    return canvas


def _other_family(dictionary: str, width: int, height: int, rng: np.random.Generator) -> Image:
    canvas = canvas_from(width, height, int(rng.integers(170, 240)))
    size = aruco_dictionary(dictionary).markerSize
    others = [f for f in FAMILIES if aruco_dictionary(f).markerSize != size]
    # from 24 px: smaller, a cell has too few pixels to tell one grid size from another
    side = float(rng.uniform(24.0, 60.0))
    y = side * 0.3
    while y + side * 1.3 < height:
        x = side * 0.3
        while x + side * 1.3 < width:
            other = others[int(rng.integers(len(others)))]
            patch, border = marker_patch(other, int(rng.integers(_ids(other))), 1)
            quad = _skewed(x, y, side, rng, 0.03)
            paste(canvas, patch, homography(border, quad), pixel_art=True)
            x += side * 1.5
        y += side * 1.5
    return canvas


#: The side of the square a pictogram is drawn in before it is put on the frame, pixels.
_PICTOGRAM_PX: Final = 64


def pictogram(symbol: str, ground: int, ink: int) -> Image:
    """A handling pictogram (:data:`PICTOGRAMS`) drawn in ``ink`` on a square of ``ground``
    (grey, :data:`_PICTOGRAM_PX` a side)."""
    art = np.full((_PICTOGRAM_PX, _PICTOGRAM_PX), ground, np.uint8)
    colour = (ink,)
    if symbol == "this_way_up":  # two arrows and a bar
        for cx in (20, 44):
            cv2.line(art, (cx, 50), (cx, 20), colour, 5)
            head = np.array([[cx - 9, 22], [cx + 9, 22], [cx, 8]], np.int32)
            cv2.fillConvexPoly(art, head, colour)
        cv2.rectangle(art, (10, 53), (54, 57), colour, -1)
    elif symbol == "keep_dry":  # an umbrella and rain drops
        cv2.ellipse(art, (32, 30), (22, 16), 0, 180, 360, colour, -1)
        cv2.line(art, (32, 30), (32, 52), colour, 3)
        cv2.ellipse(art, (28, 52), (4, 4), 0, 0, 180, colour, 3)
        for x in (14, 50):
            cv2.line(art, (x, 8), (x - 3, 14), colour, 2)
    elif symbol == "fragile":  # a wine glass with a crack
        bowl = np.array([[18, 10], [46, 10], [38, 34], [26, 34]], np.int32)
        cv2.fillConvexPoly(art, bowl, colour)
        cv2.line(art, (32, 34), (32, 50), colour, 3)
        cv2.line(art, (22, 52), (42, 52), colour, 4)
        cv2.line(art, (26, 12), (34, 22), (ground,), 2)
    elif symbol == "do_not_stack":  # two boxes, crossed out
        cv2.rectangle(art, (20, 30), (44, 52), colour, 3)
        cv2.rectangle(art, (20, 8), (44, 26), colour, 3)
        cv2.line(art, (12, 8), (52, 52), colour, 3)
        cv2.line(art, (52, 8), (12, 52), colour, 3)
    else:
        raise SceneError(f"unknown pictogram {symbol!r} (known: {PICTOGRAMS})")
    return art


def _pictograms(dictionary: str, width: int, height: int, rng: np.random.Generator) -> Image:
    del dictionary  # the symbols are the same whatever the dictionary
    canvas = canvas_from(width, height, int(rng.integers(120, 200)))  # cardboard grey
    outline = patch_outline(_PICTOGRAM_PX, _PICTOGRAM_PX)
    y = 10.0
    while y + 40.0 < height:
        x = 10.0
        while x + 40.0 < width:
            side = float(rng.uniform(14.0, 34.0))
            symbol = PICTOGRAMS[int(rng.integers(len(PICTOGRAMS)))]
            art = pictogram(symbol, int(rng.integers(15, 60)), int(rng.integers(190, 250)))
            quad = _skewed(x, y, side, rng, 0.08)  # a box face seen slightly askew
            paste(canvas, art, homography(outline, quad), pixel_art=False)
            x += side * 1.8
        y += 40.0
    return canvas


def lookalike_frame(
    kind: str, dictionary: str, rng: np.random.Generator, width: int = 640, height: int = 480
) -> Image:
    """One BGRA frame of look-alikes of ``kind`` (:data:`DRAWN_KINDS`) for ``dictionary``:
    it holds no marker of ``dictionary``, so every id read on it is false."""
    draw = {
        "keys": _keys,
        "text": _text,
        "tiles": _tiles,
        "other_family": _other_family,
        "pictograms": _pictograms,
    }
    if kind not in draw:
        raise SceneError(f"unknown look-alike kind {kind!r} (known: {DRAWN_KINDS})")
    canvas = draw[kind](dictionary, width, height, rng)
    blur = float(rng.uniform(0.0, 0.8))
    if blur > 0.3:
        canvas = u8(cv2.GaussianBlur(canvas, (0, 0), blur))
    return to_bgra(jpeg(canvas, int(rng.integers(60, 95))))


def true_tag_frame(
    dictionary: str,
    rng: np.random.Generator,
    *,
    side_px: tuple[float, float] = (10.0, 60.0),
    width: int = 640,
    height: int = 480,
) -> tuple[Image, list[TrueTag]]:
    """A BGRA frame of true markers of ``dictionary`` (sides in ``side_px``) on a light ground:
    some oblique, the frame blurred, partly in shadow and JPEG'd; and the markers drawn."""
    canvas = canvas_from(width, height, int(rng.integers(150, 235)))
    tags: list[TrueTag] = []
    top = max(side_px)
    step = top * 1.8
    y = top * 0.4
    while y + step < height:
        x = top * 0.4
        while x + step < width:
            side = float(rng.uniform(*side_px))
            tag_id = int(rng.integers(_ids(dictionary)))
            patch, border = marker_patch(
                dictionary, tag_id, 1, int(rng.integers(0, 60)), int(rng.integers(170, 256))
            )
            oblique = rng.random() < 0.4
            quad = _skewed(x, y, side, rng, 0.15 if oblique else 0.01)
            if oblique:  # foreshortened: one pair of sides shorter
                squeeze = float(rng.uniform(0.5, 0.8))
                centre = quad.mean(axis=0)
                quad[:, 0] = centre[0] + (quad[:, 0] - centre[0]) * squeeze
            paste(canvas, patch, homography(border, quad), pixel_art=True)
            tags.append(TrueTag(tag_id, quad))
            x += step
        y += step
    # a shadow over part of the frame, a soft blur, then the camera's JPEG
    shade = np.ones((height, width), np.float32)
    x0 = int(rng.integers(0, width // 2))
    shade[:, x0 : x0 + width // 3] = float(rng.uniform(0.35, 0.7))
    soft = np.asarray(cv2.GaussianBlur(shade, (0, 0), 8.0), np.float32)
    canvas = u8(np.clip(canvas * soft[:, :, None], 0, 255))
    canvas = u8(cv2.GaussianBlur(canvas, (0, 0), float(rng.uniform(0.3, 0.9))))
    return to_bgra(jpeg(canvas, int(rng.integers(60, 95)))), tags
