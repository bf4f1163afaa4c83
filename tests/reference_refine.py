"""Pre-optimisation implementation of :mod:`zenoh_perception.detect.refine`, kept verbatim to
check the optimised one against (``tests/test_refine_reference.py``): same corners, fits and
verdicts. Not used by the service.

Original module docstring:

Sub-pixel corners from the border edges, and a photometric model fit of a whole marker.

Pure numpy + OpenCV. Both work on batches of markers (:func:`refine_many`, :func:`fit_many`):
one ``cv2.remap`` samples every marker of a frame and a handful of numpy calls process all the
samples, because on small arrays a numpy call's fixed cost (microseconds) dwarfs its
arithmetic; per-marker geometry is plain Python floats for the same reason.

Pixel convention: OpenCV's (and the scene generator's): the centre of pixel (row r, col c) is
at (x=c, y=r). Marker corners are the outer corners of the black border, ordered as
``cv2.aruco`` reports them (top-left, top-right, bottom-right, bottom-left of the marker).

Corner refinement (:func:`refine_corners`)
    Each side of the border is crossed by 8 intensity profiles reaching half a cell (at most
    4 px, or 2.5 blur sigmas on blurred edges) into the black border and into the white quiet
    zone. A normalised blurred step integrates to the edge position (unbiased for any
    symmetric blur), and ``f (1 - f)`` integrates to the blur (sigma / sqrt(pi)), measured per
    axis of the marker since motion blur is directional. A line is fitted through each side's
    edge points and neighbouring lines are intersected; passes repeat until the corners move
    less than a tolerance. Median centre error about 0.02 px on the bench scenes (OpenCV's
    default corners: 0.2 px).

Model fit (:func:`fit_marker`)
    The marker as it must look, the white quiet ring, the black border and its code cells,
    blurred as its border edges measured (per axis; a few widths are tried when the edges could
    not be measured), is compared with the image sampled on a 4x4 grid per cell through the
    homography of the refined corners. Brightness and contrast are fitted by least squares over
    the whole patch; the score is the RMS residual over the code cells, beyond the image noise
    measured on the flat middle of the border cells, divided by the fitted contrast (so neither
    lighting nor sensor noise makes a marker fail). Real markers score low at every scale;
    look-alikes do not: a code printed without a quiet zone (grey plate where white should be),
    bright blobs or pictogram strokes (round cells, joined cells, holes where four white cells
    meet). The threshold grows for small cells, where blur hides the difference, and with the
    noise (:func:`acceptance_threshold`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

Gray = npt.NDArray[np.uint8]
Quad = npt.NDArray[np.float64]
Floats = npt.NDArray[np.float64]

#: Blur widths (Gaussian sigma, image pixels) tried by the model fit.
FIT_SIGMAS_PX: Final = (0.35, 0.55, 0.8, 1.1, 1.5, 2.0, 2.8)
#: Blur widths tried around the measured edge blur (factors).
FIT_BLUR_FACTORS: Final = (0.92, 1.0, 1.08)
#: Smallest cell (pixels) whose edge blur measure constrains the fit.
MIN_CELL_FOR_BLUR_PX: Final = 4.0
#: Smallest cell (pixels) whose border middle is flat enough to measure the noise on.
MIN_CELL_FOR_NOISE_PX: Final = 3.0
_MAX_NOISE_SHARE: Final = 0.75  # noise never explains more than this share of the residual
#: Samples per cell and per axis in the model fit.
FIT_SAMPLES_PER_CELL: Final = 4

_ALONG: Final = np.linspace(0.15, 0.85, 8)  # profile positions along a side (fraction)
_HALF_PROFILE_PX: Final = 4.0  # profiles reach this far from the edge (or 2.5 blur sigma)...
_BLUR_REACH: Final = 2.5
_HALF_PROFILE_CELLS: Final = 0.5  # ...and at most half a cell (border / quiet zone middle)
_PROFILE_STEP_PX: Final = 0.5  # sample spacing wanted across the edge
_PROFILE_SAMPLES: Final = (9, 17)  # min, max samples per profile
_MIN_EDGE_CONTRAST: Final = 8.0  # grey levels between border and quiet zone
_MIN_FIT_CONTRAST: Final = 10.0  # grey levels between black and white in the model fit
_MAX_SHIFT_CELLS: Final = 0.75  # a refinement that moves a corner further is refused


def _phi(z: Floats) -> Floats:
    """Standard normal CDF (Abramowitz & Stegun 7.1.26 for erf, error < 2e-7)."""
    x = np.abs(z) / math.sqrt(2.0)
    t = 1.0 / (1.0 + 0.3275911 * x)
    poly = t * (
        0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    )
    erf = 1.0 - poly * np.exp(-x * x)
    out: Floats = 0.5 * (1.0 + np.sign(z) * erf)
    return out


# cv2's stubs demand a second map; OpenCV takes None when the first holds (x, y) pairs.
_remap: Any = cv2.remap


def _sample(gray: Gray, points: npt.NDArray[np.floating[Any]]) -> Floats:
    """Bilinear samples of ``gray`` at (N, 2) continuous pixel coordinates (the values are
    rounded to integers, as OpenCV does for uint8 images)."""
    xy = points.astype(np.float32).reshape(1, -1, 2)
    values = _remap(gray, xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out: Floats = np.asarray(values, dtype=np.float64).reshape(-1)
    return out


@dataclass(frozen=True, slots=True)
class Refined:
    """Refined corners and the blur measured across the border edges.

    Blur: Gaussian sigma (pixels) of the outer border edges, bilinear sampling included, per
    axis of the marker (motion blur is directional); underestimated when the profiles could
    not reach 2.5 sigma past the edge (half a cell on small markers).
    """

    corners: Quad
    blur_x_px: float  # across the left and right sides (along the marker's x axis)
    blur_y_px: float  # across the top and bottom sides
    profile_px: float  # how far the last profiles reached on each side of the edges

    @property
    def blur_px(self) -> float:
        return max(self.blur_x_px, self.blur_y_px)

    @property
    def blur_reliable(self) -> bool:
        """The profiles reached 2.5 sigma past the edge: the blur measure is not truncated."""
        return self.profile_px >= _BLUR_REACH * self.blur_px


def refine_corners(
    gray: Gray, corners: Quad, cells: int, max_iterations: int = 4, tolerance_px: float = 0.2
) -> Refined | None:
    """Corners of the marker's outer border edges, refined to sub-pixel accuracy.

    ``cells`` is the marker's width in cells, border included (6 for 4x4 dictionaries).
    Profiles reach half a cell at most, so a start far off a small marker's edges converges
    over several iterations (each removes most of the error); iterations stop when no corner
    moves by more than ``tolerance_px`` (two usually suffice). Returns None when the edges
    cannot be measured (too little contrast between border and quiet zone, degenerate quad,
    or a correction larger than 0.75 cell).
    """
    return refine_many(gray, [corners], cells, max_iterations, tolerance_px)[0]


def refine_many(
    gray: Gray,
    quads: Sequence[Quad],
    cells: int,
    max_iterations: int = 4,
    tolerance_px: float = 0.2,
) -> list[Refined | None]:
    """:func:`refine_corners` for several markers at once: each iteration samples all the
    markers still moving with one ``cv2.remap`` and a few numpy calls (their fixed cost is
    what a single marker pays for)."""
    starts = [np.asarray(q, dtype=np.float64).reshape(4, 2).tolist() for q in quads]
    current: list[list[list[float]]] = [list(map(list, q)) for q in starts]
    reach = [_HALF_PROFILE_PX] * len(quads)
    blur = [(0.0, 0.0)] * len(quads)
    used = [_HALF_PROFILE_PX] * len(quads)
    failed = [False] * len(quads)
    active = list(range(len(quads)))
    for _ in range(max_iterations):
        if not active:
            break
        outcomes = _refine_batch(
            gray, [current[i] for i in active], cells, [reach[i] for i in active]
        )
        still: list[int] = []
        for i, outcome in zip(active, outcomes, strict=True):
            if outcome is None:
                failed[i] = True
                continue
            quad, blur[i], used[i] = outcome
            moved = _largest_move(quad, current[i])
            current[i] = quad
            wanted = max(_HALF_PROFILE_PX, _BLUR_REACH * max(blur[i]))  # blurred: look further
            if moved >= tolerance_px or wanted > reach[i]:
                reach[i] = wanted
                still.append(i)
        active = still
    out: list[Refined | None] = []
    for i, start in enumerate(starts):
        if failed[i]:
            out.append(None)
            continue
        side = min(math.dist(start[k], start[(k + 1) % 4]) for k in range(4))
        shift = _largest_move(current[i], start)
        if shift > _MAX_SHIFT_CELLS * side / cells:
            out.append(None)
            continue
        out.append(Refined(np.array(current[i]), blur[i][0], blur[i][1], used[i]))
    return out


_ALONG_LIST: Final = [float(t) for t in _ALONG]
_NEXT: Final = np.array([1, 2, 3, 0])
_UNIT_PROFILES: dict[int, tuple[Floats, npt.NDArray[np.float32]]] = {}


def _profile_plan(ns: int) -> tuple[Floats, npt.NDArray[np.float32]]:
    """For ``ns`` samples per profile: the (4 * nt * ns, 12) matrix turning the 12 side
    vectors (4 start corners, 4 side vectors, 4 half-profile normals) into sample points, and
    the (ns, 3) matrix giving the mean of the two samples at each end of a profile and the
    sum of its samples."""
    plan = _UNIT_PROFILES.get(ns)
    if plan is None:
        unit = np.linspace(-1.0, 1.0, ns)
        coef = np.zeros((4, _ALONG.size, ns, 12))
        for side in range(4):
            coef[side, :, :, side] = 1.0
            coef[side, :, :, 4 + side] = _ALONG[:, None]
            coef[side, :, :, 8 + side] = unit[None, :]
        ends = np.zeros((ns, 3), dtype=np.float32)
        ends[:2, 0] = 0.5
        ends[-2:, 1] = 0.5
        ends[:, 2] = 1.0
        plan = (coef.reshape(-1, 12), ends)
        _UNIT_PROFILES[ns] = plan
    return plan


def _largest_move(a: list[list[float]], b: list[list[float]]) -> float:
    return max(max(abs(p[0] - q[0]), abs(p[1] - q[1])) for p, q in zip(a, b, strict=True))


_Side = tuple[float, float, float, float, float, float, float]  # x0 y0 dx dy nx ny half


def _sides(quad: list[list[float]], cells: int, reach_px: float) -> list[_Side] | None:
    """Per side: start, direction, outward unit normal and half profile length."""
    area = 0.0
    for i in range(4):
        (x0, y0), (x1, y1) = quad[i], quad[(i + 1) % 4]
        area += x0 * y1 - y0 * x1
    # outward normals: (u_y, -u_x) for the clockwise (y down) order cv2.aruco reports
    sign = 1.0 if area > 0 else -1.0
    sides: list[_Side] = []
    for i in range(4):
        (x0, y0), (x1, y1) = quad[i], quad[(i + 1) % 4]
        dx, dy = x1 - x0, y1 - y0
        length = math.hypot(dx, dy)
        if length < 4.0:
            return None
        nx, ny = sign * dy / length, -sign * dx / length
        sides.append((x0, y0, dx, dy, nx, ny, min(length * _HALF_PROFILE_CELLS / cells, reach_px)))
    return sides


def _refine_batch(
    gray: Gray, quads: list[list[list[float]]], cells: int, reaches: list[float]
) -> list[tuple[list[list[float]], tuple[float, float], float] | None]:
    """One pass for each quad: profiles across the four sides, one line per side, corners
    where they meet.

    Geometry is done with Python floats and the profiles of all quads with a handful of
    numpy calls on one array: a numpy call costs microseconds whatever its size, far more
    than the arithmetic on a few points (this runs for every candidate and tracked marker).
    """
    geometry = [_sides(q, cells, r) for q, r in zip(quads, reaches, strict=True)]
    valid = [g for g in geometry if g is not None]
    if not valid:
        return [None] * len(quads)
    widest = max(side[6] for g in valid for side in g)
    lo_n, hi_n = _PROFILE_SAMPLES
    ns = min(max(2 * math.ceil(widest / _PROFILE_STEP_PX) + 1, lo_n), hi_n)
    coef, ends = _profile_plan(ns)
    vectors = np.array(
        [
            [side[0:2] for side in g]
            + [side[2:4] for side in g]
            + [(side[6] * side[4], side[6] * side[5]) for side in g]
            for g in valid
        ]
    )  # (m, 12, 2): 4 start corners, 4 side vectors, 4 half-profile normals
    points = np.matmul(coef, vectors).astype(np.float32).reshape(1, -1, 2)
    samples = _remap(gray, points, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    v = np.asarray(samples, dtype=np.float32).reshape(-1, ns)  # (m * 4 * nt, ns)
    # per profile: inside (border) level, outside (quiet zone) level, sum, sum of squares;
    # the normalised profile f = (v - low) / span is never formed (fewer numpy calls)
    low, high, v_sum = (v @ ends).T.tolist()
    v_sq = np.einsum("ij,ij->i", v, v).tolist()
    out: list[tuple[list[list[float]], tuple[float, float], float] | None] = []
    block = 0
    per_quad = 4 * len(_ALONG_LIST)
    for g in geometry:
        if g is None:
            out.append(None)
            continue
        out.append(_lines_to_corners(g, ns, block, low=low, high=high, v_sum=v_sum, v_sq=v_sq))
        block += per_quad
    return out


def _lines_to_corners(
    sides: list[_Side],
    ns: int,
    first: int,
    *,
    low: list[float],
    high: list[float],
    v_sum: list[float],
    v_sq: list[float],
) -> tuple[list[list[float]], tuple[float, float], float] | None:
    """Edge positions of one quad's profiles -> a line per side -> corners, and blur."""
    nt = len(_ALONG_LIST)
    step_unit = 2.0 / (ns - 1)
    lines: list[tuple[float, float, float, float]] = []
    weights = [0.0, 0.0]  # x (left / right sides), y (top / bottom)
    spreads = [0.0, 0.0]
    for i in range(4):
        x0, y0, dx, dy, nx, ny, half = sides[i]
        step = half * step_unit
        sw = st = stt = so = sto = 0.0
        for k in range(nt):
            j = first + i * nt + k
            span = high[j] - low[j]
            if span <= _MIN_EDGE_CONTRAST:
                continue
            t = _ALONG_LIST[k]
            # a normalised step integrates to its position; f (1 - f) to sigma / sqrt(pi)
            f_sum = (v_sum[j] - ns * low[j]) / span
            f_sq = (v_sq[j] - 2.0 * low[j] * v_sum[j] + ns * low[j] * low[j]) / (span * span)
            offset = step * (ns - 0.5 - f_sum) - half
            sw += 1.0
            st += t
            stt += t * t
            so += offset
            sto += offset * t
            spreads[(i + 1) % 2] += (f_sum - f_sq) * step
        if sw < 3.0:
            return None
        # offset = a + b t along the side: the refined line
        b = (sw * sto - st * so) / (sw * stt - st * st)
        a = (so - b * st) / sw
        lines.append((x0 + a * nx, y0 + a * ny, dx + b * nx, dy + b * ny))
        weights[(i + 1) % 2] += sw
    corners: list[list[float]] = []
    for i in range(4):  # corner i is where side i-1 meets side i
        px, py, ux, uy = lines[i - 1]
        qx, qy, vx, vy = lines[i]
        cross = ux * vy - uy * vx
        if abs(cross) < 1e-6 * (ux * ux + uy * uy):
            return None
        t = ((qx - px) * vy - (qy - py) * vx) / cross
        x, y = px + t * ux, py + t * uy
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        corners.append([x, y])
    root_pi = math.sqrt(math.pi)
    blur = (root_pi * spreads[0] / weights[0], root_pi * spreads[1] / weights[1])
    return corners, blur, min(side[6] for side in sides)


@dataclass(frozen=True, slots=True)
class FitResult:
    """How well the image matches the ideal marker.

    ``score``: RMS residual / fitted contrast (0 = perfect). ``sigma_px``: best blur width.
    ``contrast``: fitted white - black, grey levels. ``cell_px``: cell size in pixels (the
    smaller of its two sides on a slanted marker).
    """

    score: float
    sigma_px: float
    contrast: float
    cell_px: float
    noise: float = 0.0  # RMS residual on the flat border middles / contrast


@dataclass(frozen=True, slots=True)
class _Models:
    """The blurred models of one marker at one scale and blur, centred over all samples, and
    their sums (of m and m^2) over the code samples and the flat-border samples."""

    centred: Floats  # (nsig, N)
    norms: list[float]  # sum(m_k^2) over all samples
    code_sums: list[float]  # sum(m_k) over the code samples
    code_norms: list[float]  # sum(m_k^2) over the code samples
    flat_sums: list[float]
    flat_norms: list[float]
    sigmas: list[float]  # blur of each model (pixels, the larger axis)


class MarkerModel:
    """Ideal appearance of the markers of one ArUco dictionary.

    The blurred models are cached per id and per cell size (in 3 % steps), so tracking a marker
    reuses them from frame to frame.
    """

    _CACHE_LIMIT: Final = 4096
    _BUCKET: Final = math.log(1.03)

    def __init__(self, dictionary: Any) -> None:
        self.dictionary = dictionary
        self.bits = int(dictionary.markerSize)
        self.cells = self.bits + 2  # with the black border
        self._darkness: dict[int, Floats] = {}
        self._coverages: dict[int, Floats] = {}
        self._stats: dict[tuple[int, int, int, int, int], _Models] = {}
        total = self.cells + 2  # with the white quiet ring
        per_axis = total * FIT_SAMPLES_PER_CELL
        # sample coordinates in cell units; the marker spans [0, cells], the ring [-1, 0]
        self._axis = (np.arange(per_axis) + 0.5) / FIT_SAMPLES_PER_CELL - 1.0
        gx, gy = np.meshgrid(self._axis, self._axis)
        self._grid = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32).reshape(-1, 1, 2)
        self._grid_h = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], axis=1)
        self._edges = np.arange(total + 1, dtype=np.float64) - 1.0  # cell boundaries
        inner = (self._axis > 1.0) & (self._axis < self.cells - 1.0)
        self.code_mask = (inner[:, None] & inner[None, :]).ravel()  # samples on the code cells
        # samples in the middle half of each border cell: flat black, they measure the noise
        phase = np.mod(self._axis, 1.0)
        middle = (phase > 0.25) & (phase < 0.75)
        marker = (self._axis > 0.0) & (self._axis < self.cells)
        border = marker[:, None] & marker[None, :] & ~(inner[:, None] & inner[None, :])
        self.flat_mask = (border & middle[:, None] & middle[None, :]).ravel()
        # (N, 3) indicators of the sample subsets: all, code, flat
        self.subsets = np.stack(
            [np.ones(self.code_mask.size), self.code_mask, self.flat_mask], axis=1
        ).astype(np.float64)
        self.code_count = int(self.code_mask.sum())
        self.flat_count = int(self.flat_mask.sum())
        size = float(self.cells)
        self._square = np.array([[0, 0], [size, 0], [size, size], [0, size]], dtype=np.float32)
        # cell centres of the marker (border included), for reading its bits
        cy, cx = np.mgrid[0 : self.cells, 0 : self.cells] + 0.5
        self.cell_centres = np.stack([cx.ravel(), cy.ravel(), np.ones(cx.size)], axis=1)
        self._black: dict[int, list[bool]] = {}

    def darkness(self, tag_id: int) -> Floats:
        """(cells + 2)^2 absorbance of ``tag_id``: 0 white (quiet ring, white bits), 1 black."""
        cached = self._darkness.get(tag_id)
        if cached is not None:
            return cached
        image = cv2.aruco.generateImageMarker(self.dictionary, tag_id, self.cells, borderBits=1)
        out = np.zeros((self.cells + 2, self.cells + 2), dtype=np.float64)
        out[1:-1, 1:-1] = 1.0 - np.asarray(image, dtype=np.float64) / 255.0
        self._darkness[tag_id] = out
        return out

    def blurred(self, tag_id: int, sigma_x: Floats, sigma_y: Floats) -> Floats:
        """(len(sigma_x), N) reflectance of the blurred marker at the fit's sample points.

        ``sigma_x`` / ``sigma_y``: blur widths in cells along the marker's own axes (they differ
        on a slanted marker). The world beyond the quiet ring counts as white.
        """
        dark = self.darkness(tag_id)
        wx = np.stack([self._coverage(float(s)) for s in sigma_x])
        wy = np.stack([self._coverage(float(s)) for s in sigma_y])
        blurred = np.matmul(np.matmul(wy, dark), wx.transpose(0, 2, 1))
        out: Floats = 1.0 - blurred.reshape(len(sigma_x), -1)
        return out

    def _coverage(self, sigma_cells: float) -> Floats:
        """(S, cells + 2): blurred coverage of each cell at each sample coordinate (cached by
        blur width in 3 % steps)."""
        bucket = round(math.log(max(sigma_cells, 1e-3)) / self._BUCKET)
        cached = self._coverages.get(bucket)
        if cached is not None:
            return cached
        sigma = math.exp(bucket * self._BUCKET)
        cdf = _phi((self._axis[:, None] - self._edges[None, :]) / sigma)
        out: Floats = cdf[:, :-1] - cdf[:, 1:]
        self._coverages[bucket] = out
        return out

    def centred(
        self, tag_id: int, cell_x: float, cell_y: float, blur: tuple[float, float] | None
    ) -> _Models:
        """The centred models (:data:`_Models`) for a marker whose cells measure ``cell_x`` by
        ``cell_y`` pixels: blurred by :data:`FIT_BLUR_FACTORS` times the measured ``blur``
        (x, y in pixels) if given, else isotropically by each of :data:`FIT_SIGMAS_PX`."""
        step = self._BUCKET
        bx = round(math.log(max(cell_x, 0.5)) / step)
        by = round(math.log(max(cell_y, 0.5)) / step)
        if blur is None:
            key = (tag_id, bx, by, -1000, -1000)
        else:
            key = (
                tag_id,
                bx,
                by,
                round(math.log(max(blur[0], 0.1)) / step),
                round(math.log(max(blur[1], 0.1)) / step),
            )
        cached = self._stats.get(key)
        if cached is not None:
            return cached
        if blur is None:
            sigma_x = sigma_y = np.asarray(FIT_SIGMAS_PX, dtype=np.float64)
        else:
            factors = np.asarray(FIT_BLUR_FACTORS, dtype=np.float64)
            sigma_x = math.exp(key[3] * step) * factors
            sigma_y = math.exp(key[4] * step) * factors
        m = self.blurred(tag_id, sigma_x / math.exp(bx * step), sigma_y / math.exp(by * step))
        mc = m - m.mean(axis=1, keepdims=True)
        sums = (mc @ self.subsets).T.tolist()  # over all, code, flat samples
        norms = ((mc * mc) @ self.subsets).T.tolist()
        entry = _Models(
            centred=mc,
            norms=[max(v, 1e-12) for v in norms[0]],
            code_sums=sums[1],
            code_norms=norms[1],
            flat_sums=sums[2],
            flat_norms=norms[2],
            sigmas=[float(v) for v in np.maximum(sigma_x, sigma_y)],
        )
        if len(self._stats) >= self._CACHE_LIMIT:
            self._stats.clear()
        self._stats[key] = entry
        return entry

    def black_cells(self, tag_id: int) -> list[bool]:
        """Which cells of marker ``tag_id`` (border included, row-major) are black."""
        cached = self._black.get(tag_id)
        if cached is None:
            cached = [bool(v > 0.5) for v in self.darkness(tag_id)[1:-1, 1:-1].ravel()]
            self._black[tag_id] = cached
        return cached

    def homography(self, corners: Quad) -> Floats:
        """(3, 3) map from marker cell coordinates to the image for a marker at ``corners``."""
        h = cv2.getPerspectiveTransform(self._square, np.asarray(corners, dtype=np.float32))
        out: Floats = np.asarray(h, dtype=np.float64)
        return out

    def sample_points(self, corners: Quad) -> npt.NDArray[np.float32]:
        """(N, 1, 2) image coordinates of the fit's sample points for a marker at ``corners``."""
        h = self.homography(corners)
        out = np.asarray(cv2.perspectiveTransform(self._grid, h), dtype=np.float32)
        return out

    def sample_many(self, gray: Gray, homographies: Floats) -> Floats:
        """(m, N) bilinear samples at the fit's points of m markers (their homographies)."""
        mapped = np.matmul(self._grid_h, homographies.transpose(0, 2, 1))  # (m, N, 3)
        xy = (mapped[:, :, :2] / mapped[:, :, 2:3]).astype(np.float32).reshape(1, -1, 2)
        samples = _remap(gray, xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out: Floats = np.asarray(samples, dtype=np.float64).reshape(len(homographies), -1)
        return out


def fit_marker(
    gray: Gray,
    corners: Quad,
    tag_id: int,
    model: MarkerModel,
    blur: tuple[float, float] | None = None,
) -> FitResult:
    """Fit the ideal marker ``tag_id`` at ``corners`` to the image (see the module doc).

    ``blur``: the (x, y) blur measured on the border edges (:class:`Refined`); the cells of a
    real marker are exactly as blurred as its border, so the fit then only tries blur widths
    near it (on cells of at least :data:`MIN_CELL_FOR_BLUR_PX`, where the edge measure is
    reliable); otherwise it tries :data:`FIT_SIGMAS_PX`.

    The score is the code-cell residual in excess of the noise (measured on the flat middle
    of the border cells), over the contrast: image noise alone does not make a marker fail.
    """
    return fit_many(gray, [(corners, tag_id, blur)], model)[0]


FitRequest = tuple[Quad, int, "tuple[float, float] | None"]


def fit_many(gray: Gray, requests: Sequence[FitRequest], model: MarkerModel) -> list[FitResult]:
    """:func:`fit_marker` for several (corners, id, blur) at once: one ``cv2.remap`` and a
    few batched numpy calls for all of them."""
    results: list[FitResult | None] = [None] * len(requests)
    todo: list[tuple[int, float, _Models]] = []
    homographies = []
    for index, (corners, tag_id, measured) in enumerate(requests):
        quad = np.asarray(corners, dtype=np.float64).reshape(4, 2)
        (x0, y0), (x1, y1), (x2, y2), (x3, y3) = quad.tolist()
        top, bottom = math.hypot(x1 - x0, y1 - y0), math.hypot(x2 - x3, y2 - y3)
        left, right = math.hypot(x3 - x0, y3 - y0), math.hypot(x2 - x1, y2 - y1)
        cell_x = (top + bottom) / (2.0 * model.cells)
        cell_y = (left + right) / (2.0 * model.cells)
        cell_px = min(cell_x, cell_y)
        if not cell_px > 0.0:
            results[index] = FitResult(math.inf, 0.0, 0.0, cell_px, math.inf)
            continue
        blur = measured
        if blur is not None and (cell_px < MIN_CELL_FOR_BLUR_PX or not min(blur) > 0.0):
            blur = None
        todo.append((index, cell_px, model.centred(tag_id, cell_x, cell_y, blur)))
        homographies.append(model.homography(quad))
    if todo:
        observed = model.sample_many(gray, np.stack(homographies))  # (m, N)
        width = max(len(item[2].sigmas) for item in todo)
        stacked = np.zeros((len(todo), width, observed.shape[1]))
        for k, item in enumerate(todo):
            stacked[k, : len(item[2].sigmas)] = item[2].centred
        split = observed[:, :, None] * model.subsets  # (m, N, 3): x over all, code, flat
        cross_all = np.matmul(stacked, split).tolist()  # (m, nsig, 3): sum(m_k x) per subset
        sums_all = (observed @ model.subsets).tolist()
        squares_all = ((observed * observed) @ model.subsets).tolist()
        n = int(observed.shape[1])
        for k, (index, cell_px, models) in enumerate(todo):
            results[index] = _score(
                models,
                model,
                cell_px,
                n,
                cross=cross_all[k],
                sums=sums_all[k],
                squares=squares_all[k],
            )
    return [r if r is not None else FitResult(math.inf, 0.0, 0.0, 0.0, math.inf) for r in results]


def _score(
    models: _Models,
    model: MarkerModel,
    cell_px: float,
    n: int,
    *,
    cross: list[list[float]],
    sums: list[float],
    squares: list[float],
) -> FitResult:
    """The fit of one marker from its sample sums (see :func:`fit_marker`)."""
    sum_all, sum_code, sum_flat = sums
    sq_all, sq_code, sq_flat = squares
    mean = sum_all / n
    syy = sq_all - sum_all * mean
    best, best_rss, c = -1, math.inf, 0.0
    for k in range(len(models.sigmas)):
        contrast = cross[k][0] / models.norms[k]  # the models are centred: no mean term
        rss = syy - cross[k][0] * contrast
        if contrast > _MIN_FIT_CONTRAST and rss < best_rss:
            best, best_rss, c = k, rss, contrast
    if best < 0:
        return FitResult(math.inf, 0.0, 0.0, cell_px, math.inf)
    code_ms = _subset_ms(
        mean,
        c,
        sq=sq_code,
        total=sum_code,
        count=model.code_count,
        cross=cross[best][1],
        msum=models.code_sums[best],
        mnorm=models.code_norms[best],
    )
    flat_ms = _subset_ms(
        mean,
        c,
        sq=sq_flat,
        total=sum_flat,
        count=model.flat_count,
        cross=cross[best][2],
        msum=models.flat_sums[best],
        mnorm=models.flat_norms[best],
    )
    noise_ms = 0.0
    if cell_px >= MIN_CELL_FOR_NOISE_PX:  # smaller border cells have no flat middle
        noise_ms = min(max(flat_ms, 0.0), _MAX_NOISE_SHARE * code_ms)
    excess = math.sqrt(max(code_ms - noise_ms, 0.0))
    return FitResult(excess / c, models.sigmas[best], c, cell_px, math.sqrt(max(flat_ms, 0.0)) / c)


def bits_match(
    gray: Gray, requests: Sequence[tuple[Quad, int]], model: MarkerModel, max_errors: int = 1
) -> list[bool]:
    """Whether the cells at the centre of each marker read as ``tag_id``'s (black border
    included, at most ``max_errors`` wrong), with one ``cv2.remap`` for all of them.

    Much cheaper than :func:`fit_marker` and enough to notice that a followed marker was
    replaced by another one at the same place (ids of a dictionary differ in several bits).
    """
    if not requests:
        return []
    homographies = np.stack([model.homography(np.asarray(q)) for q, _ in requests])
    mapped = np.matmul(model.cell_centres, homographies.transpose(0, 2, 1))
    xy = (mapped[:, :, :2] / mapped[:, :, 2:3]).astype(np.float32).reshape(1, -1, 2)
    samples = _remap(gray, xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    values = np.asarray(samples, dtype=np.float64).reshape(len(requests), -1).tolist()
    out: list[bool] = []
    for row, (_, tag_id) in zip(values, requests, strict=True):
        black = model.black_cells(tag_id)
        dark = [v for v, b in zip(row, black, strict=True) if b]
        light = [v for v, b in zip(row, black, strict=True) if not b]
        if not dark or not light:
            out.append(False)
            continue
        low, high = sum(dark) / len(dark), sum(light) / len(light)
        if high - low < _MIN_FIT_CONTRAST:
            out.append(False)
            continue
        middle = (low + high) / 2.0
        errors = sum((v > middle) == b for v, b in zip(row, black, strict=True))
        out.append(errors <= max_errors)
    return out


def _subset_ms(
    mean: float,
    c: float,
    *,
    sq: float,
    total: float,
    count: int,
    cross: float,
    msum: float,
    mnorm: float,
) -> float:
    """Mean of (x - mean - c m)^2 over a subset of samples, from the subset's sums of x, x^2,
    x m, m and m^2."""
    centred_sq = sq - 2.0 * mean * total + count * mean * mean
    centred_cross = cross - mean * msum
    return float(centred_sq - 2.0 * c * centred_cross + c * c * mnorm) / count


def acceptance_threshold(cell_px: float, noise: float = 0.0) -> float:
    """Largest model-fit score of a real marker with cells of ``cell_px`` pixels, in an image
    whose noise (RMS, in units of the marker's contrast) is ``noise``.

    Calibrated on generated scenes (realistic effects, four resolutions and a drive; harsh
    effects for the noise term): it accepts about 99 % of the real markers the scan finds
    with cells of 4 px and more, and 90-95 % of those with 2-3 px cells, where blur and noise
    hide the cells' shape; look-alikes that pass are those whose fit is as good as a marker's
    (about 3 % of the look-alikes OpenCV's default detector decodes, all with cells under 6 px).
    """
    return 0.04 + 0.3 / max(cell_px, 1.0) ** 2 + max(0.0, min(noise, 0.3) - 0.04)
