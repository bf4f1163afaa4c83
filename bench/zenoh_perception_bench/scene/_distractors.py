"""Marker-like distractors: dark squares that OpenCV's default ArUco detector tends to decode.

With DICT_4X4_50 the default detector corrects no bit errors (maxCorrectionBits 1 x
errorCorrectionRate 0.6 rounds down to 0), so a look-alike fools it only if its 4x4 interior
reads exactly as a valid code. The "blob", "glyph" and "bare_code" kinds therefore hide a real
code pattern (`mimic_id`, random rotation) in shapes a real tag never has:

- "blob": dark box with soft, round bright blobs (a lamp / reflections behind a dark window).
- "glyph": dark box with crisp bright strokes joining the white cells (a pictogram sign).
- "bare_code": the crisp code with no white quiet zone, on a larger dark or textured plate.
- "decoy": dark box with a random bright glyph, no code (rarely decoded; clutter realism).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._effects import colourise, lowpass_noise
from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._raster import marker_cells, patch_outline, u8

#: Every distractor kind.
DISTRACTOR_KINDS: tuple[str, ...] = ("blob", "glyph", "bare_code", "decoy")
#: Kinds that carry a valid code pattern (the ones a default detector decodes).
CODE_DISTRACTOR_KINDS: tuple[str, ...] = ("blob", "glyph", "bare_code")

_SHIFT = 4  # cv2 drawing sub-pixel bits
_ONE = 1 << _SHIFT


@dataclass(frozen=True)
class DistractorArt:
    """A rendered distractor: opaque BGR patch, the outline (TL, TR, BR, BL) of its dark core
    square in patch pixel coordinates, and the plate-to-core size ratio (>= 1)."""

    patch: npt.NDArray[np.uint8]
    core: npt.NDArray[np.float64]
    plate_ratio: float
    mimic_id: int | None


def check_kinds(kinds: tuple[str, ...]) -> None:
    """SceneError unless every kind is known."""
    bad = [k for k in kinds if k not in DISTRACTOR_KINDS]
    if bad or not kinds:
        raise SceneError(f"distractor kinds must be a non-empty subset of {DISTRACTOR_KINDS}")


def plate_ratio(kind: str, rng: np.random.Generator) -> float:
    """Footprint / core side ratio for a kind (the plate around a bare code)."""
    return float(rng.uniform(1.3, 1.8)) if kind == "bare_code" else 1.0


def _pt(x: float, y: float) -> tuple[int, int]:
    return (round(x * _ONE), round(y * _ONE))


def _dark(rng: np.random.Generator) -> tuple[float, float, float]:
    base = float(rng.uniform(0, 55))
    tint = rng.uniform(-8, 8, 3)
    c = np.clip(base + tint, 0, 255)
    return (float(c[0]), float(c[1]), float(c[2]))


def _bright(rng: np.random.Generator) -> tuple[float, float, float]:
    palette = np.array(
        [[245, 245, 245], [120, 230, 250], [90, 200, 255], [150, 250, 150], [250, 220, 170]],
        dtype=np.float64,
    )
    c = palette[int(rng.integers(len(palette)))] * float(rng.uniform(0.75, 1.0))
    return (float(c[0]), float(c[1]), float(c[2]))


def _white_bits(dictionary: str, mimic_id: int, quarter_turns: int) -> npt.NDArray[np.bool_]:
    """(C, C) bool, True on white cells of the code (rotated), border included (all False)."""
    cells = marker_cells(dictionary, mimic_id) > 127
    return np.rot90(cells, quarter_turns)


def _cell_centre(row: int, col: int, cell: int) -> tuple[float, float]:
    return ((col + 0.5) * cell - 0.5, (row + 0.5) * cell - 0.5)


def _draw_code_shapes(
    layer: npt.NDArray[np.float32],
    white: npt.NDArray[np.bool_],
    cell: int,
    rng: np.random.Generator,
    *,
    stroke: tuple[float, float],
    radius: tuple[float, float],
    jitter: float,
) -> None:
    """Bright shapes on a 0..1 layer: a disc on each white cell, strokes between 4-neighbours."""
    size = white.shape[0]
    centres: dict[tuple[int, int], tuple[float, float]] = {}
    for r in range(size):
        for c in range(size):
            if white[r, c]:
                x, y = _cell_centre(r, c, cell)
                dx, dy = rng.uniform(-jitter, jitter, 2) * cell
                centres[(r, c)] = (x + float(dx), y + float(dy))
    for (r, c), (x, y) in centres.items():
        rad = float(rng.uniform(*radius)) * cell
        cv2.circle(layer, _pt(x, y), round(rad * _ONE), 1.0, -1, cv2.LINE_AA, _SHIFT)
        for nr, nc in ((r, c + 1), (r + 1, c)):
            if (nr, nc) in centres:
                thick = max(1, round(float(rng.uniform(*stroke)) * cell))
                x2, y2 = centres[(nr, nc)]
                cv2.line(layer, _pt(x, y), _pt(x2, y2), 1.0, thick, cv2.LINE_AA, _SHIFT)


def _mix(
    layer: npt.NDArray[np.float32],
    low: tuple[float, float, float],
    high: tuple[float, float, float],
) -> npt.NDArray[np.uint8]:
    lo = np.array(low, dtype=np.float32)
    hi = np.array(high, dtype=np.float32)
    out = lo + layer[:, :, None] * (hi - lo)
    return u8(np.clip(np.rint(out), 0, 255))


def render_distractor(
    kind: str,
    dictionary: str,
    mimic_id: int | None,
    *,
    side_px: float,
    ratio: float,
    rng: np.random.Generator,
) -> DistractorArt:
    """Draw one distractor whose core square will appear about `side_px` pixels wide; `ratio` is
    the plate / core side ratio (from `plate_ratio`, only used by "bare_code")."""
    size = marker_cells(dictionary, 0).shape[0]
    cell = max(6, min(40, math.ceil(side_px / size)))
    core_px = size * cell
    quarter = int(rng.integers(4))
    if kind in CODE_DISTRACTOR_KINDS and mimic_id is None:
        raise SceneError(f"distractor kind {kind!r} needs a mimic_id")
    if kind == "blob":
        layer = np.zeros((core_px, core_px), dtype=np.float32)
        white = _white_bits(dictionary, int(mimic_id or 0), quarter)
        _draw_code_shapes(
            layer, white, cell, rng, stroke=(0.8, 1.0), radius=(0.46, 0.54), jitter=0.04
        )
        sigma = float(rng.uniform(0.08, 0.2)) * cell
        layer = np.asarray(cv2.GaussianBlur(layer, (0, 0), sigma), dtype=np.float32)
        patch = _mix(layer, _dark(rng), _bright(rng))
        return DistractorArt(patch, patch_outline(core_px, core_px), 1.0, mimic_id)
    if kind == "glyph":
        layer = np.zeros((core_px, core_px), dtype=np.float32)
        white = _white_bits(dictionary, int(mimic_id or 0), quarter)
        _draw_code_shapes(
            layer, white, cell, rng, stroke=(0.62, 0.85), radius=(0.44, 0.5), jitter=0.02
        )
        patch = _mix(layer, _dark(rng), _bright(rng))
        return DistractorArt(patch, patch_outline(core_px, core_px), 1.0, mimic_id)
    if kind == "bare_code":
        plate_px = core_px + 2 * max(1, round(core_px * (ratio - 1.0) / 2.0))
        index = lowpass_noise(plate_px, plate_px, rng, float(rng.uniform(0.5, 2.0)) * cell, 3)
        low = float(rng.uniform(35, 90))
        high = low + float(rng.uniform(30, 90))
        patch = colourise(index, (low, low, low), (high, high, high))
        tint = rng.uniform(-10, 10, 3)
        patch = u8(np.clip(patch.astype(np.int16) + tint.astype(np.int16), 0, 255))
        cells = np.rot90(marker_cells(dictionary, int(mimic_id or 0)), quarter)
        black = int(rng.integers(0, 30))
        white_level = int(rng.integers(170, 250))
        code = np.where(cells > 127, white_level, black).astype(np.uint8)
        code = u8(cv2.resize(code, (core_px, core_px), interpolation=cv2.INTER_NEAREST))
        off = (plate_px - core_px) // 2
        patch[off : off + core_px, off : off + core_px] = code[:, :, None]
        core = patch_outline(core_px, core_px) + off
        return DistractorArt(patch, core, plate_px / core_px, mimic_id)
    if kind == "decoy":
        layer = np.zeros((core_px, core_px), dtype=np.float32)
        inner = core_px - 2 * cell
        style = int(rng.integers(3))
        if style == 0:  # one big bright spot
            r = float(rng.uniform(0.15, 0.4)) * inner
            x, y = rng.uniform(cell + r, core_px - cell - r, 2)
            cv2.circle(
                layer, _pt(float(x), float(y)), round(r * _ONE), 1.0, -1, cv2.LINE_AA, _SHIFT
            )
            layer = np.asarray(cv2.GaussianBlur(layer, (0, 0), 0.15 * r), dtype=np.float32)
        elif style == 1:  # a letter or digit (putText draws on 8-bit images only)
            text = "ABEFHKPRSTXZ0123456789"[int(rng.integers(22))]
            scale = inner / 24.0
            (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, cell))
            org = (round((core_px - tw) / 2), round((core_px + th) / 2))
            glyph = np.zeros((core_px, core_px), dtype=np.uint8)
            cv2.putText(
                glyph, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 255, max(1, cell), cv2.LINE_AA
            )
            layer = glyph.astype(np.float32) / np.float32(255.0)
        else:  # arrow-like pictogram
            c = core_px / 2.0
            a = float(rng.uniform(0, 2 * math.pi))
            dx, dy = math.cos(a) * inner * 0.35, math.sin(a) * inner * 0.35
            thick = max(1, round(cell * 0.8))
            cv2.arrowedLine(
                layer,
                _pt(c - dx, c - dy),
                _pt(c + dx, c + dy),
                1.0,
                thick,
                cv2.LINE_AA,
                _SHIFT,
                0.4,
            )
        patch = _mix(layer, _dark(rng), _bright(rng))
        return DistractorArt(patch, patch_outline(core_px, core_px), 1.0, None)
    raise SceneError(f"unknown distractor kind {kind!r} (known: {DISTRACTOR_KINDS})")
