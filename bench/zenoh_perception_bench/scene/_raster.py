"""Anti-aliased placement of marker bitmaps and other square patches at sub-pixel quads.

A patch of w x h pixels has its outer corners at (-0.5, -0.5), (w-0.5, -0.5), (w-0.5, h-0.5),
(-0.5, h-0.5) in its own pixel coordinates (centre of pixel (r, c) at (c, r)); a homography maps
those coordinates to the canvas, which uses the same convention. The patch is warped with
bilinear interpolation onto a k-times finer grid (k chosen so patch pixels are not minified
there), pixel-art patches (marker cells) are first replicated so that one patch pixel is about
one fine pixel, and the fine grid is box-filtered back (INTER_AREA). Coverage is warped with the
patch (premultiplied), so edges against the background are anti-aliased and unbiased.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._geometry import f64

_MAX_SUPERSAMPLE = 8
_FINE_BUDGET_PX = 12_000_000
_MAX_PIXEL_ART_SIDE = 4096


def u8(value: object) -> npt.NDArray[np.uint8]:
    """`value` as a uint8 array (no copy when it already is one)."""
    return np.asarray(value, dtype=np.uint8)


@functools.lru_cache(maxsize=32)
def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """A predefined cv2.aruco dictionary by name, e.g. "DICT_4X4_50"."""
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        raise SceneError(f"unknown ArUco dictionary {name!r}")
    return cv2.aruco.getPredefinedDictionary(code)


def dictionary_size(name: str) -> int:
    """Number of ids in a predefined dictionary."""
    return int(aruco_dictionary(name).bytesList.shape[0])


@functools.lru_cache(maxsize=4096)
def marker_cells(name: str, tag_id: int) -> npt.NDArray[np.uint8]:
    """Marker bitmap, one pixel per cell including the 1-cell black border, 0 / 255, read-only."""
    dictionary = aruco_dictionary(name)
    count = int(dictionary.bytesList.shape[0])
    if not 0 <= tag_id < count:
        raise SceneError(f"tag id {tag_id} out of range for {name} (0..{count - 1})")
    side = int(dictionary.markerSize) + 2
    cells = u8(cv2.aruco.generateImageMarker(dictionary, tag_id, side, borderBits=1)).copy()
    cells.flags.writeable = False
    return cells


def with_quiet_zone(cells: npt.NDArray[np.uint8], quiet_zone_bits: int) -> npt.NDArray[np.uint8]:
    """Cell bitmap padded with `quiet_zone_bits` white cells on each side."""
    if quiet_zone_bits < 0:
        raise SceneError(f"quiet_zone_bits must be >= 0, got {quiet_zone_bits}")
    if quiet_zone_bits == 0:
        return cells
    return np.pad(cells, quiet_zone_bits, mode="constant", constant_values=255)


def homography(src: npt.ArrayLike, dst: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """3x3 homography mapping 4 source points to 4 destination points (float64 DLT)."""
    s = f64(src).reshape(4, 2)
    d = f64(dst).reshape(4, 2)
    a = np.zeros((8, 8))
    b = np.zeros(8)
    for i in range(4):
        x, y = s[i]
        u, v = d[i]
        a[2 * i] = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y]
        a[2 * i + 1] = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y]
        b[2 * i], b[2 * i + 1] = u, v
    try:
        h = np.linalg.solve(a, b)
    except np.linalg.LinAlgError as err:
        raise SceneError("degenerate quad (three corners on a line?)") from err
    return np.append(h, 1.0).reshape(3, 3)


def apply_homography(h: npt.NDArray[np.float64], points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Map points (N, 2) through a homography."""
    pts = f64(points).reshape(-1, 2)
    hom = np.hstack([pts, np.ones((pts.shape[0], 1))]) @ h.T
    out: npt.NDArray[np.float64] = hom[:, :2] / hom[:, 2:3]
    return out


def patch_outline(width: int, height: int) -> npt.NDArray[np.float64]:
    """Outer corners (TL, TR, BR, BL) of a width x height patch in its pixel coordinates."""
    return np.array(
        [[-0.5, -0.5], [width - 0.5, -0.5], [width - 0.5, height - 0.5], [-0.5, height - 0.5]]
    )


def check_quad(quad: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """A finite, strictly convex quad (4, 2) as float64, else SceneError."""
    try:
        q = f64(quad).reshape(4, 2)
    except (ValueError, TypeError) as err:
        raise SceneError(f"a quad must be 4 (x, y) points, got {quad!r}") from err
    if not np.all(np.isfinite(q)):
        raise SceneError("quad corners must be finite")
    edges = np.roll(q, -1, axis=0) - q
    cross = (
        edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, 0)[:, 0]
    )
    if not (np.all(cross > 1e-9) or np.all(cross < -1e-9)):
        raise SceneError("quad must be strictly convex with corners in order")
    return q


def paste(
    canvas: npt.NDArray[np.uint8],
    patch: npt.NDArray[np.uint8],
    h_patch_to_canvas: npt.NDArray[np.float64],
    *,
    pixel_art: bool,
) -> None:
    """Composite `patch` (gray or BGR, fully opaque) onto the BGR `canvas` in place."""
    img_h, img_w = canvas.shape[:2]
    ph, pw = patch.shape[:2]
    outline = apply_homography(h_patch_to_canvas, patch_outline(pw, ph))
    x0 = max(math.floor(outline[:, 0].min() + 0.5) - 1, 0)
    x1 = min(math.floor(outline[:, 0].max() + 0.5) + 2, img_w)
    y0 = max(math.floor(outline[:, 1].min() + 0.5) - 1, 0)
    y1 = min(math.floor(outline[:, 1].max() + 0.5) + 2, img_h)
    if x0 >= x1 or y0 >= y1:
        return
    side = np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1)
    scales = side / np.array([pw, ph, pw, ph], dtype=np.float64)  # canvas px per patch px
    s_min, s_max = float(scales.min()), float(scales.max())
    roi_w, roi_h = x1 - x0, y1 - y0
    k = math.ceil((8.0 if pixel_art else 1.0) / max(s_min, 1e-6))
    k = max(1, min(k, _MAX_SUPERSAMPLE))
    if roi_w * roi_h * 4 <= 2_000_000:
        k = max(k, 2)
    while k > 1 and roi_w * roi_h * k * k > _FINE_BUDGET_PX:
        k -= 1
    src = patch
    h_total = h_patch_to_canvas
    if pixel_art:
        # one replicated pixel ~ one fine pixel: bilinear ramps then box-filter like area
        m = max(1, min(round(s_max * k), _MAX_PIXEL_ART_SIDE // max(ph, pw)))
        if m > 1:
            src = u8(cv2.resize(patch, (pw * m, ph * m), interpolation=cv2.INTER_NEAREST))
            up = np.array([[1.0 / m, 0.0, 0.5 / m - 0.5], [0.0, 1.0 / m, 0.5 / m - 0.5], [0, 0, 1]])
            h_total = h_total @ up
    fine = np.array([[k, 0.0, k * (0.5 - x0) - 0.5], [0.0, k, k * (0.5 - y0) - 0.5], [0, 0, 1]])
    h_total = fine @ h_total
    planes = [src] if src.ndim == 2 else list(cv2.split(src))
    channels = len(planes)
    stack = u8(cv2.merge([*planes, np.full(src.shape[:2], 255, dtype=np.uint8)]))
    warped = u8(
        cv2.warpPerspective(
            stack,
            h_total,
            (roi_w * k, roi_h * k),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(0, 0, 0, 0),
        )
    )
    if k > 1:
        warped = u8(cv2.resize(warped, (roi_w, roi_h), interpolation=cv2.INTER_AREA))
    warped_planes = list(cv2.split(warped))
    cover = u8(warped_planes[channels])
    if channels == 1:
        colour = u8(cv2.cvtColor(warped_planes[0], cv2.COLOR_GRAY2BGR))
    else:
        colour = u8(cv2.merge(warped_planes[:channels]))
    keep = u8(cv2.cvtColor(255 - cover, cv2.COLOR_GRAY2BGR))
    roi = canvas[y0:y1, x0:x1]
    kept = cv2.multiply(roi, keep, scale=1.0 / 255.0)
    roi[...] = cv2.add(kept, colour)


def marker_patch(
    dictionary: str,
    tag_id: int,
    quiet_zone_bits: int,
    black: int = 0,
    white: int = 255,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float64]]:
    """Marker cell bitmap with quiet zone and ink levels, plus the outline (4, 2) of its black
    border square in the bitmap's pixel coordinates (TL, TR, BR, BL)."""
    cells = marker_cells(dictionary, tag_id)
    padded = with_quiet_zone(cells, quiet_zone_bits)
    if (black, white) != (0, 255):
        lut = np.array([black, white], dtype=np.uint8)
        padded = lut[(padded > 127).astype(np.intp)]
    q = float(quiet_zone_bits)
    c = float(cells.shape[0])
    border = np.array(
        [
            [q - 0.5, q - 0.5],
            [q + c - 0.5, q - 0.5],
            [q + c - 0.5, q + c - 0.5],
            [q - 0.5, q + c - 0.5],
        ]
    )
    return np.ascontiguousarray(padded), border


def paste_marker(
    canvas: npt.NDArray[np.uint8],
    dictionary: str,
    tag_id: int,
    corners: npt.ArrayLike,
    *,
    quiet_zone_bits: int = 1,
    black: int = 0,
    white: int = 255,
) -> None:
    """Draw one marker whose black-border outer corners land exactly on `corners` (4, 2)."""
    quad = check_quad(corners)
    patch, border = marker_patch(dictionary, tag_id, quiet_zone_bits, black, white)
    paste(canvas, patch, homography(border, quad), pixel_art=True)


def to_bgra(bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """Opaque C-contiguous BGRA copy of a BGR image."""
    return np.ascontiguousarray(u8(cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)))


def canvas_from(width: int, height: int, background: int | npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """A fresh BGR canvas: a gray level, a (B, G, R) colour, or a copy of an image."""
    if width < 1 or height < 1:
        raise SceneError(f"image size must be positive, got {width}x{height}")
    bg = np.asarray(background)
    if bg.ndim == 0 or (bg.ndim == 1 and bg.shape[0] in (3, 4)):
        colour = np.broadcast_to(bg, (3,)) if bg.ndim == 0 else bg[:3]
        if np.any(colour < 0) or np.any(colour > 255):
            raise SceneError(f"background levels must be in 0..255, got {background!r}")
        out = np.empty((height, width, 3), dtype=np.uint8)
        fill = (float(colour[0]), float(colour[1]), float(colour[2]))
        cv2.rectangle(out, (0, 0), (width - 1, height - 1), fill, -1)
        return out
    if bg.shape[:2] != (height, width) or bg.dtype != np.uint8:
        raise SceneError(
            f"background image must be uint8 of size {height}x{width}, got {bg.dtype} {bg.shape}"
        )
    if bg.ndim == 2:
        return u8(cv2.cvtColor(bg, cv2.COLOR_GRAY2BGR))
    if bg.ndim == 3 and bg.shape[2] == 3:
        return bg.copy()
    if bg.ndim == 3 and bg.shape[2] == 4:
        return u8(cv2.cvtColor(bg, cv2.COLOR_BGRA2BGR))
    raise SceneError(f"background image must have 1, 3 or 4 channels, got shape {bg.shape}")


def render_markers(
    width: int,
    height: int,
    markers: Sequence[tuple[int, npt.ArrayLike]],
    *,
    dictionary: str = "DICT_4X4_50",
    background: int | npt.ArrayLike = 255,
    quiet_zone_bits: int = 1,
) -> npt.NDArray[np.uint8]:
    """Flat render of markers `(tag_id, corners (4, 2))` at exact sub-pixel quads, no effects.

    `corners` are the outer corners of each marker's black border (TL, TR, BR, BL in the
    marker's own frame) in continuous image coordinates. `background` is a gray level, a BGR
    colour or an image (gray, BGR or BGRA of the same size). Returns BGRA uint8 (H, W, 4).
    """
    canvas = canvas_from(width, height, background)
    for tag_id, corners in markers:
        paste_marker(canvas, dictionary, int(tag_id), corners, quiet_zone_bits=quiet_zone_bits)
    return to_bgra(canvas)
