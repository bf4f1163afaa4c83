"""Sub-pixel corners from the border edges, and a photometric model fit of a whole marker.

Pure numpy + OpenCV. Both work on batches of markers (:func:`refine_many`, :func:`fit_many`):
one ``cv2.remap`` samples every marker of a frame and a handful of numpy calls process all the
samples, because on small arrays a numpy call's fixed cost (microseconds) dwarfs its
arithmetic; per-marker geometry is plain Python floats for the same reason.
(``tests/test_refine_reference.py`` checks the results against the simpler implementation
this one replaced, kept as ``tests/reference_refine.py``.)

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
import operator
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
_NO_BLUR: Final = -1000  # blur buckets of a model cache key when no blur was measured
_BUCKET: Final = math.log(1.03)  # models are cached by cell size and blur in 3 % steps
_SMALLEST_SIGMA_CELLS: Final = 1e-3
# The bucket of a blur width sigma (cells) is round(log(sigma) / _BUCKET). The model fit
# blurs by sigma = exp(k _BUCKET) * f pixels (k: bucket of the measured blur, f: one of
# FIT_BLUR_FACTORS) or by sigma = s (one of FIT_SIGMAS_PX), on cells of exp(b _BUCKET) pixels
# (b: bucket of the cell size): the bucket of sigma in cells is round(k - b + log(f) /
# _BUCKET) = k - b + round(log(f) / _BUCKET), or round(log(s) / _BUCKET) - b, exactly: the
# fractional parts of log(f) / _BUCKET and log(s) / _BUCKET are at least 0.016 from 1/2, far
# more than the rounding errors of the logarithms (1e-12), and integer arithmetic replaces
# a logarithm per sigma (tests/test_refine_reference.py checks it against the logarithms).
_FACTOR_BUCKETS: Final = [round(math.log(f) / _BUCKET) for f in FIT_BLUR_FACTORS]
_SIGMA_BUCKETS: Final = [round(math.log(s) / _BUCKET) for s in FIT_SIGMAS_PX]
_LOWEST_BUCKET: Final = round(math.log(_SMALLEST_SIGMA_CELLS) / _BUCKET)


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


_REMAP_WIDTH: Final = 32766  # cv2.remap wants fewer than SHRT_MAX columns


def _remap(gray: Gray, x: npt.NDArray[np.float32], y: npt.NDArray[np.float32]) -> Floats:
    """Bilinear samples of ``gray`` at the (rows, columns) coordinates ``x``, ``y`` (rounded
    to integers, as OpenCV does for uint8 images). Sampled as one row when they fit in one:
    OpenCV splits a remap by rows over threads, which costs more than it saves on the few
    thousand points of a frame's markers. A colour image gives one more axis, its channels."""
    shape = x.shape
    if x.size <= _REMAP_WIDTH:
        x, y = x.reshape(1, -1), y.reshape(1, -1)
    samples = np.asarray(
        cv2.remap(gray, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
        dtype=np.float64,
    )
    out: Floats = samples.reshape(shape + samples.shape[2:])
    return out


def _sample_mapped(gray: Gray, homographies: Floats, points_t: Floats) -> Floats:
    """(m, n) bilinear samples of ``gray`` at the (3, n) homogeneous ``points_t`` mapped by
    each of the (m, 3, 3) ``homographies``: one matrix product and one ``cv2.remap``."""
    m = len(homographies)
    # rows: the x, then y, then w coordinates of every marker's points
    mapped = (homographies.transpose(1, 0, 2).reshape(3 * m, 3) @ points_t).reshape(3, m, -1)
    x, y = (mapped[:2] / mapped[2]).astype(np.float32)
    return _remap(gray, x, y)


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
    if not quads:
        return []
    # quads as flat lists x0 y0 x1 y1 x2 y2 x3 y3 of Python floats (cheapest to unpack)
    starts = np.array([np.asarray(q, dtype=np.float64).reshape(8) for q in quads]).tolist()
    current = list(starts)
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
    corners = np.array(current).reshape(-1, 4, 2)
    out: list[Refined | None] = []
    hypot = math.hypot
    for i, (x0, y0, x1, y1, x2, y2, x3, y3) in enumerate(starts):
        if failed[i]:
            out.append(None)
            continue
        side = min(hypot(x1 - x0, y1 - y0), hypot(x2 - x1, y2 - y1))
        side = min(side, hypot(x3 - x2, y3 - y2), hypot(x0 - x3, y0 - y3))
        if _largest_move(current[i], starts[i]) > _MAX_SHIFT_CELLS * side / cells:
            out.append(None)
            continue
        out.append(Refined(corners[i], blur[i][0], blur[i][1], used[i]))
    return out


_NT: Final = _ALONG.size
_UNIT_PROFILES: dict[int, tuple[Floats, Floats]] = {}
# (3 nt, 9): per side, the sums over its profiles of three per-profile values, each weighted
# by 1, t and t^2 (t: the profile's position along the side)
_POWERS: Final = np.kron(np.eye(3), np.stack([np.ones(_NT), _ALONG, _ALONG * _ALONG], axis=1))


def _profile_plan(ns: int) -> tuple[Floats, Floats]:
    """For ``ns`` samples per profile: the (3, nt * ns) matrix turning a side's start,
    side vector and half-profile normal (x or y components) into the coordinates of its
    samples, and the (4, ns) matrix giving, from a profile's samples v, the level inside
    the border low = mean of the first two, the span = mean of the last two - low, and
    sum(v) - ns low, 2 sum(v) - ns low (exact: small multiples of halves)."""
    plan = _UNIT_PROFILES.get(ns)
    if plan is None:
        unit = np.linspace(-1.0, 1.0, ns)
        coef = np.zeros((3, _NT, ns))
        coef[0] = 1.0
        coef[1] = _ALONG[:, None]
        coef[2] = unit[None, :]
        ends = np.zeros((4, ns))
        ends[0, :2] = 0.5
        ends[1, -2:] = 0.5
        ends[1, :2] = -0.5
        ends[2:, :] = [[1.0], [2.0]]
        ends[2:, :2] -= ns * 0.5
        plan = (coef.reshape(3, -1), ends)
        _UNIT_PROFILES[ns] = plan
    return plan


def _largest_move(a: list[float], b: list[float]) -> float:
    """Largest coordinate change between two flat quads."""
    move: float = max(map(abs, map(operator.sub, a, b)))
    return move


_Side = tuple[float, float, float, float, float, float, float]  # x0 y0 dx dy nx ny half
# per side: x0 dx half * nx, then the same for y; the largest half profile length
_Geometry = tuple[list[_Side], list[float], list[float], float]


def _sides(quad: list[float], cells: int, reach_px: float) -> _Geometry | None:
    """Per side: start, direction, outward unit normal and half profile length (and the
    rows of the matrix giving its sample coordinates, see _refine_batch)."""
    x0, y0, x1, y1, x2, y2, x3, y3 = quad
    area = (x0 * y1 - y0 * x1) + (x1 * y2 - y1 * x2) + (x2 * y3 - y2 * x3) + (x3 * y0 - y3 * x0)
    # outward normals: (u_y, -u_x) for the clockwise (y down) order cv2.aruco reports
    sign = 1.0 if area > 0 else -1.0
    sides: list[_Side] = []
    xs: list[float] = []
    ys: list[float] = []
    widest = 0.0
    for xa, ya, xb, yb in ((x0, y0, x1, y1), (x1, y1, x2, y2), (x2, y2, x3, y3), (x3, y3, x0, y0)):
        dx, dy = xb - xa, yb - ya
        length = math.hypot(dx, dy)
        if length < 4.0:
            return None
        nx, ny = sign * dy / length, -sign * dx / length
        half = min(length * _HALF_PROFILE_CELLS / cells, reach_px)
        sides.append((xa, ya, dx, dy, nx, ny, half))
        xs += (xa, dx, half * nx)
        ys += (ya, dy, half * ny)
        widest = max(widest, half)
    return sides, xs, ys, widest


def _refine_batch(
    gray: Gray, quads: list[list[float]], cells: int, reaches: list[float]
) -> list[tuple[list[float], tuple[float, float], float] | None]:
    """One pass for each quad: profiles across the four sides, one line per side, corners
    where they meet.

    Per-marker geometry is done with Python floats; the profiles of all quads are sampled
    with one matrix product and one ``cv2.remap``, and reduced to the few sums each side's
    line fit needs with a dozen numpy calls on (profiles,) arrays and one more product: a
    numpy call costs microseconds whatever its size, far more than the arithmetic on a few
    points, and a Python loop over every profile costs more than both (this runs for every
    candidate and tracked marker).
    """
    geometry = [_sides(q, cells, r) for q, r in zip(quads, reaches, strict=True)]
    xs: list[float] = []  # per side, x components then y: start, side vector, half normal
    ys: list[float] = []
    widest = 0.0
    for g in geometry:
        if g is not None:
            xs += g[1]
            ys += g[2]
            widest = max(widest, g[3])
    if not xs:
        return [None] * len(quads)
    lo_n, hi_n = _PROFILE_SAMPLES
    ns = min(max(2 * math.ceil(widest / _PROFILE_STEP_PX) + 1, lo_n), hi_n)
    coef, ends = _profile_plan(ns)
    coords = (np.array(xs + ys).reshape(-1, 3) @ coef).astype(np.float32)  # (2 * sides, nt ns)
    x, y = coords.reshape(2, len(xs) // 3, -1)
    v = _remap(gray, x, y).reshape(-1, ns)  # (profiles, ns)
    # per profile: inside (border) level, span to the outside (quiet zone) level, and
    # with f = (v - low) / span the normalised profile (never formed: fewer numpy calls),
    # span f_sum = sum(v) - ns low and span^2 f_sq = sum(v^2) - low (2 sum(v) - ns low)
    low, span, centred_sum, twice = (ends @ v.T).reshape(4, -1, _NT)
    centred_sq = np.einsum("ij,ij->i", v, v).reshape(-1, _NT) - low * twice
    # per side and profile: measured (enough contrast), f_sum and f_sum - f_sq where
    # measured, else 0: a normalised step integrates to its position, f (1 - f) to
    # sigma / sqrt(pi)
    per_side = np.empty((len(low), 3, _NT))
    measured, steps, spreads = per_side.transpose(1, 0, 2)
    np.greater(span, _MIN_EDGE_CONTRAST, out=measured)
    inverse = measured / np.maximum(span, _MIN_EDGE_CONTRAST)
    np.multiply(centred_sum, inverse, out=steps)
    np.multiply(centred_sum - centred_sq * inverse, inverse, out=spreads)
    sums = (per_side.reshape(-1, 3 * _NT) @ _POWERS).tolist()  # per side: 9 sums
    out: list[tuple[list[float], tuple[float, float], float] | None] = []
    k = 0
    for g in geometry:
        if g is None:
            out.append(None)
            continue
        out.append(_lines_to_corners(g[0], ns, sums[k : k + 4]))
        k += 4
    return out


def _lines_to_corners(
    sides: list[_Side], ns: int, sums: list[list[float]]
) -> tuple[list[float], tuple[float, float], float] | None:
    """One quad's profile sums -> a line per side -> corners, and blur.

    ``sums``, per side, over its measured profiles: the number of profiles and the sums of
    their t and t^2, the sums of f_sum and t f_sum, then (at 6) the sum of f_sum - f_sq
    (f: the normalised profile, t: its position along the side).
    """
    lines: list[tuple[float, float, float, float]] = []
    weight_x = weight_y = spread_x = spread_y = 0.0  # left / right sides, top / bottom
    unit = 2.0 / (ns - 1)
    for i in range(4):
        x0, y0, dx, dy, nx, ny, half = sides[i]
        sw, st, stt, sf, stf, _, spread, _, _ = sums[i]
        if sw < 3.0:
            return None
        # an edge at offset o from the side has f_sum = ns - 0.5 - (o + half) / step
        step = half * unit
        base = step * (ns - 0.5) - half
        so = base * sw - step * sf
        sto = base * st - step * stf
        # offset = a + b t along the side: the refined line
        b = (sw * sto - st * so) / (sw * stt - st * st)
        a = (so - b * st) / sw
        lines.append((x0 + a * nx, y0 + a * ny, dx + b * nx, dy + b * ny))
        if i & 1:
            weight_x += sw
            spread_x += spread * step
        else:
            weight_y += sw
            spread_y += spread * step
    corners: list[float] = []
    px, py, ux, uy = lines[3]
    for qx, qy, vx, vy in lines:  # corner i is where side i-1 meets side i
        cross = ux * vy - uy * vx
        if abs(cross) < 1e-6 * (ux * ux + uy * uy):
            return None
        t = ((qx - px) * vy - (qy - py) * vx) / cross
        x, y = px + t * ux, py + t * uy
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        corners += (x, y)
        px, py, ux, uy = qx, qy, vx, vy
    blur = (_ROOT_PI * spread_x / weight_x, _ROOT_PI * spread_y / weight_y)
    return corners, blur, min(sides[0][6], sides[1][6], sides[2][6], sides[3][6])


_ROOT_PI: Final = math.sqrt(math.pi)


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
    _BUCKET: Final = _BUCKET

    def __init__(self, dictionary: Any) -> None:
        self.dictionary = dictionary
        self.bits = int(dictionary.markerSize)
        self.cells = self.bits + 2  # with the black border
        # darkness of each id and blurred coverages of each blur width (_coverage_rows_of),
        # as rows of a table gathered with one numpy call
        self._dark_rows: dict[int, int] = {}
        self._dark_table: Floats = np.zeros((0, self.cells + 2, self.cells + 2))
        self._coverage_rows: dict[int, int] = {}
        self._stats: dict[tuple[int, int, int, int, int], _Models] = {}
        total = self.cells + 2  # with the white quiet ring
        per_axis = total * FIT_SAMPLES_PER_CELL
        # sample coordinates in cell units; the marker spans [0, cells], the ring [-1, 0]
        self._axis = (np.arange(per_axis) + 0.5) / FIT_SAMPLES_PER_CELL - 1.0
        gx, gy = np.meshgrid(self._axis, self._axis)
        self._grid_t = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])  # (3, N) homogeneous
        self._edges = np.arange(total + 1, dtype=np.float64) - 1.0  # cell boundaries
        # sample - cell edge offsets: few distinct values (the samples are on a grid)
        offsets = self._axis[:, None] - self._edges[None, :]
        self._offsets, index = np.unique(offsets, return_inverse=True)
        self._offset_index = index.reshape(offsets.shape)
        self._coverage_table: Floats = np.zeros((64, per_axis, total))  # grows by doubling
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
        self._subset_rows = np.ascontiguousarray(self.subsets.T)  # (3, N)
        self._mean_weights = np.full(self.code_mask.size, 1.0 / self.code_mask.size)
        self.code_count = int(self.code_mask.sum())
        self.flat_count = int(self.flat_mask.sum())
        size = float(self.cells)
        self._square = np.array([[0, 0], [size, 0], [size, size], [0, size]], dtype=np.float32)
        # cell centres of the marker (border included), for reading its bits
        cy, cx = np.mgrid[0 : self.cells, 0 : self.cells] + 0.5
        self.cell_centres = np.stack([cx.ravel(), cy.ravel(), np.ones(cx.size)], axis=1)
        self._centres_t = np.ascontiguousarray(self.cell_centres.T)  # (3, cells^2)
        self._black: dict[int, list[bool]] = {}

    def darkness(self, tag_id: int) -> Floats:
        """(cells + 2)^2 absorbance of ``tag_id``: 0 white (quiet ring, white bits), 1 black."""
        row = self._dark_row(tag_id)  # may grow the table: before indexing it
        out: Floats = self._dark_table[row]
        return out

    def _dark_row(self, tag_id: int) -> int:
        """Row of ``tag_id``'s darkness in the darkness table (added on first use)."""
        row = self._dark_rows.get(tag_id)
        if row is None:
            image = cv2.aruco.generateImageMarker(self.dictionary, tag_id, self.cells, borderBits=1)
            dark = np.zeros((1, self.cells + 2, self.cells + 2), dtype=np.float64)
            dark[0, 1:-1, 1:-1] = 1.0 - np.asarray(image, dtype=np.float64) / 255.0
            row = self._dark_rows[tag_id] = len(self._dark_table)
            self._dark_table = np.concatenate([self._dark_table, dark])
        return row

    def blurred(self, tag_id: int, sigma_x: Floats, sigma_y: Floats) -> Floats:
        """(len(sigma_x), N) reflectance of the blurred marker at the fit's sample points.

        ``sigma_x`` / ``sigma_y``: blur widths in cells along the marker's own axes (they differ
        on a slanted marker). The world beyond the quiet ring counts as white.
        """
        step = self._BUCKET
        buckets = [
            round(math.log(max(float(s), _SMALLEST_SIGMA_CELLS)) / step)
            for s in (*sigma_x, *sigma_y)
        ]
        rows = self._coverage_rows_of(buckets)
        wx, wy = self._coverage_table[rows].reshape(
            2, len(sigma_x), *self._coverage_table.shape[1:]
        )
        darkness = self.darkness(tag_id)
        out: Floats = 1.0 - np.matmul(np.matmul(wy, darkness), wx.transpose(0, 2, 1)).reshape(
            len(sigma_x), -1
        )
        return out

    _COVERAGE_BLOCK: Final = 64

    def _coverage_rows_of(self, buckets: list[int]) -> list[int]:
        """Rows of the coverage table for these blur buckets (widths in cells, 3 % steps): the
        (S, cells + 2) blurred coverage of each cell at each sample coordinate. Missing ones
        are computed together, with the rest of their block of neighbouring buckets (the
        blur and size of the markers seen so far are those likely to come)."""
        rows = self._coverage_rows
        try:
            return [rows[b] for b in buckets]
        except KeyError:
            pass
        size = self._COVERAGE_BLOCK
        missing = sorted({b // size for b in buckets if b not in rows})
        new = [b for block in missing for b in range(block * size, (block + 1) * size)]
        new = [b for b in new if b not in rows]
        sigma = np.array([math.exp(b * self._BUCKET) for b in new])
        # the CDF at each (sample - cell edge) offset: _phi of the distinct offsets only
        cdf = _phi(self._offsets[None, :] / sigma[:, None])[:, self._offset_index]
        first = len(rows)
        table = self._coverage_table
        if first + len(new) > len(table):
            table = np.zeros((2 * (first + len(new)), *table.shape[1:]))
            table[:first] = self._coverage_table[:first]
            self._coverage_table = table
        table[first : first + len(new)] = cdf[:, :, :-1] - cdf[:, :, 1:]
        rows.update((b, first + k) for k, b in enumerate(new))
        return [rows[b] for b in buckets]

    def _key(
        self, tag_id: int, cell_x: float, cell_y: float, blur: tuple[float, float] | None
    ) -> tuple[int, int, int, int, int]:
        """Cache key of :meth:`centred`: id, cell size and blur in 3 % steps."""
        step = self._BUCKET
        bx = round(math.log(max(cell_x, 0.5)) / step)
        by = round(math.log(max(cell_y, 0.5)) / step)
        if blur is None:
            return (tag_id, bx, by, _NO_BLUR, _NO_BLUR)
        return (
            tag_id,
            bx,
            by,
            round(math.log(max(blur[0], 0.1)) / step),
            round(math.log(max(blur[1], 0.1)) / step),
        )

    def centred(
        self, tag_id: int, cell_x: float, cell_y: float, blur: tuple[float, float] | None
    ) -> _Models:
        """The centred models (:data:`_Models`) for a marker whose cells measure ``cell_x`` by
        ``cell_y`` pixels: blurred by :data:`FIT_BLUR_FACTORS` times the measured ``blur``
        (x, y in pixels) if given, else isotropically by each of :data:`FIT_SIGMAS_PX`."""
        return self._models([self._key(tag_id, cell_x, cell_y, blur)])[0]

    def _models(self, keys: list[tuple[int, int, int, int, int]]) -> list[_Models]:
        """:meth:`centred` for several cache keys; those not cached are computed together."""
        found = [self._stats.get(key) for key in keys]
        missing = list(dict.fromkeys(k for k, e in zip(keys, found, strict=True) if e is None))
        if not missing:
            return [e for e in found if e is not None]
        computed = dict(zip(missing, self._compute(missing), strict=True))
        for key, entry in computed.items():
            if len(self._stats) >= self._CACHE_LIMIT:
                self._stats.clear()
            self._stats[key] = entry
        return [e if e is not None else computed[k] for k, e in zip(keys, found, strict=True)]

    def _compute(self, keys: list[tuple[int, int, int, int, int]]) -> list[_Models]:
        """The models of several cache keys (see :meth:`centred`), with a dozen numpy calls
        for all of them."""
        # keys with a measured blur (one model per factor) first, then the others (one per
        # width); per model, its blur buckets (cells) along y and x (see _FACTOR_BUCKETS)
        measured = [key for key in keys if key[3] != _NO_BLUR]
        ordered = measured + [key for key in keys if key[3] == _NO_BLUR]
        ys: list[int] = []
        xs: list[int] = []
        sigmas: list[list[float]] = []
        for _, bx, by, blur_x, blur_y in measured:
            ys += map((blur_y - by).__add__, _FACTOR_BUCKETS)
            xs += map((blur_x - bx).__add__, _FACTOR_BUCKETS)
            widest = math.exp(max(blur_x, blur_y) * self._BUCKET)  # pixels, the larger axis
            sigmas.append(list(map(widest.__mul__, FIT_BLUR_FACTORS)))
        for _, bx, by, _, _ in ordered[len(measured) :]:
            ys += map((-by).__add__, _SIGMA_BUCKETS)
            xs += map((-bx).__add__, _SIGMA_BUCKETS)
            sigmas.append(list(FIT_SIGMAS_PX))
        buckets = ys + xs
        if min(buckets) < _LOWEST_BUCKET:
            buckets = [max(b, _LOWEST_BUCKET) for b in buckets]
        rows = self._coverage_rows_of(buckets)  # may grow the table: before indexing it
        coverages = self._coverage_table[rows]
        t = len(xs)
        edges = self.cells + 2
        dark_rows = [self._dark_row(key[0]) for key in ordered]  # may grow the table: first
        darkness = self._dark_table[dark_rows]
        # the y coverages times the darkness: one product per key (its models share it)
        split = len(measured) * len(FIT_BLUR_FACTORS)
        parts = [
            np.matmul(wy.reshape(len(dark), -1, edges), dark).reshape(-1, edges)
            for wy, dark in (
                (coverages[:split], darkness[: len(measured)]),
                (coverages[split:t], darkness[len(measured) :]),
            )
            if len(dark)
        ]
        wy_dark = parts[0] if len(parts) == 1 else np.concatenate(parts)
        blurred = np.matmul(wy_dark.reshape(t, -1, edges), coverages[t:].transpose(0, 2, 1))
        blurred = blurred.reshape(t, -1)
        # the models m = 1 - blurred, centred over all samples (in place); sums over the
        # samples as matrix-vector products (numpy's means and matrix-matrix products cost
        # more on these shapes)
        mc = np.subtract((blurred @ self._mean_weights)[:, None], blurred, out=blurred)
        squares = mc * mc
        everything, code, flat = self._subset_rows
        stats = np.stack(
            [squares @ everything, mc @ code, squares @ code, mc @ flat, squares @ flat]
        )
        np.maximum(stats[0], 1e-12, out=stats[0])
        norms, code_sums, code_norms, flat_sums, flat_norms = stats.tolist()
        computed: dict[tuple[int, int, int, int, int], _Models] = {}
        first = 0
        for key, sigma in zip(ordered, sigmas, strict=True):
            last = first + len(sigma)
            computed[key] = _Models(
                centred=mc[first:last],
                norms=norms[first:last],
                code_sums=code_sums[first:last],
                code_norms=code_norms[first:last],
                flat_sums=flat_sums[first:last],
                flat_norms=flat_norms[first:last],
                sigmas=sigma,
            )
            first = last
        return [computed[key] for key in keys]

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

    def cell_samples(self, image: Gray, corners: Sequence[Quad]) -> Floats:
        """(m, cells * cells) bilinear samples at the cell centres (border included, row-major)
        of m markers at ``corners``; (m, cells * cells, channels) from a colour image."""
        homographies = np.stack([self.homography(np.asarray(q)) for q in corners])
        return _sample_mapped(image, homographies, self._centres_t)

    def sample_many(self, gray: Gray, homographies: Floats) -> Floats:
        """(m, N) bilinear samples at the fit's points of m markers (their homographies)."""
        return _sample_mapped(gray, homographies, self._grid_t)


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
    """:func:`fit_marker` for several (corners, id, blur) at once: one ``cv2.remap`` for all
    of them, the models not cached yet computed together, then one small matrix product per
    marker."""
    if not requests:
        return []
    results: list[FitResult | None] = [None] * len(requests)
    todo: list[tuple[int, float]] = []
    keys: list[tuple[int, int, int, int, int]] = []
    homographies = []
    quads = np.array([np.asarray(c, dtype=np.float64).reshape(4, 2) for c, _, _ in requests])
    for index, ((x0, y0, x1, y1, x2, y2, x3, y3), (_, tag_id, measured)) in enumerate(
        zip(quads.reshape(-1, 8).tolist(), requests, strict=True)
    ):
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
        todo.append((index, cell_px))
        keys.append(model._key(tag_id, cell_x, cell_y, blur))
        homographies.append(model.homography(quads[index]))
    if todo:
        all_models = model._models(keys)
        observed = model.sample_many(gray, np.stack(homographies))  # (m, N)
        split = observed[:, None, :] * model._subset_rows  # (m, 3, N): x over all, code, flat
        sums_all = split.sum(axis=2).tolist()
        squares_all = (observed * observed @ model.subsets).tolist()
        n = int(observed.shape[1])
        for k, ((index, cell_px), models) in enumerate(zip(todo, all_models, strict=True)):
            results[index] = _score(
                models,
                model,
                cell_px,
                n,
                cross=(models.centred @ split[k].T).tolist(),  # (nsig, 3): sum(m_k x) per subset
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
    values = model.cell_samples(gray, [q for q, _ in requests]).tolist()
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
