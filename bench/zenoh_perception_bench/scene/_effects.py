"""Backgrounds, clutter and image-level effects (lighting, contrast, blur, motion blur, noise).

Everything works on BGR uint8 images with OpenCV primitives (the generator must stay fast at
HD2K) and draws all randomness from the caller's numpy Generator. What real cameras add on top
(colour casts, tone, shadows, glare, greyscale sensors, rolling shutter, JPEG) is described by
`Effects.camera` and lives in `_camera_effects`.
"""

from __future__ import annotations

import math
import string
from dataclasses import dataclass, field, fields
from statistics import NormalDist

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._camera_effects import CameraEffects, CameraParams
from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._raster import u8

#: Background kinds understood by `Effects.backgrounds`.
BACKGROUND_KINDS: tuple[str, ...] = ("plain", "gradient", "textured")

_UNIT_NORMAL_LEVELS = np.array(
    [NormalDist().inv_cdf((i + 0.5) / 256.0) for i in range(256)], dtype=np.float64
)
_FONTS = (
    cv2.FONT_HERSHEY_SIMPLEX,
    cv2.FONT_HERSHEY_DUPLEX,
    cv2.FONT_HERSHEY_COMPLEX,
    cv2.FONT_HERSHEY_TRIPLEX,
    cv2.FONT_HERSHEY_PLAIN,
)


def _check_range(name: str, value: tuple[float, float], low: float, high: float) -> None:
    if len(value) != 2 or not (low <= value[0] <= value[1] <= high):
        raise SceneError(f"Effects.{name} must be (min, max) within [{low}, {high}], got {value}")


@dataclass(frozen=True)
class EffectParams:
    """The effect values drawn for one scene (or one drive) from an `Effects` description."""

    background: str = "plain"
    clutter: int = 0
    blur_sigma: float = 0.0
    motion_blur_px: float = 0.0
    motion_angle_deg: float = 0.0
    noise_sigma: float = 0.0
    lighting_gradient: float = 0.0
    lighting_angle_deg: float = 0.0
    brightness: float = 0.0
    contrast: float = 1.0
    camera: CameraParams = field(default_factory=CameraParams)


@dataclass(frozen=True)
class Effects:
    """Which effects to apply and how strongly: every field is a (min, max) range sampled
    uniformly per scene (per drive for `SceneGenerator.drive`); (0, 0) disables an effect.

    - backgrounds: kinds drawn from ("plain", "gradient", "textured").
    - clutter: number of random rectangles, lines, circles, text and noise patches.
    - blur_sigma: Gaussian blur sigma (px). motion_blur_px: motion blur length (px, any angle).
    - noise_sigma: additive Gaussian noise per channel (gray levels, truncated at 2.9 sigma).
    - lighting_gradient: depth g of a multiplicative linear gradient, gain from 1 to 1 - g.
    - brightness: additive offset (gray levels). contrast: gain about mid-gray 128.
    - marker_black / marker_white: ink levels of printed markers (per marker).
    - camera: what real cameras add (`CameraEffects`; off unless asked for).
    """

    backgrounds: tuple[str, ...] = ("plain",)
    clutter: tuple[int, int] = (0, 0)
    blur_sigma: tuple[float, float] = (0.0, 0.0)
    motion_blur_px: tuple[float, float] = (0.0, 0.0)
    noise_sigma: tuple[float, float] = (0.0, 0.0)
    lighting_gradient: tuple[float, float] = (0.0, 0.0)
    brightness: tuple[float, float] = (0.0, 0.0)
    contrast: tuple[float, float] = (1.0, 1.0)
    marker_black: tuple[int, int] = (0, 0)
    marker_white: tuple[int, int] = (255, 255)
    camera: CameraEffects = field(default_factory=CameraEffects)

    def __post_init__(self) -> None:
        if not self.backgrounds or any(b not in BACKGROUND_KINDS for b in self.backgrounds):
            raise SceneError(
                f"Effects.backgrounds must be a non-empty subset of {BACKGROUND_KINDS}, "
                f"got {self.backgrounds!r}"
            )
        _check_range("clutter", self.clutter, 0, 1000)
        _check_range("blur_sigma", self.blur_sigma, 0.0, 20.0)
        _check_range("motion_blur_px", self.motion_blur_px, 0.0, 50.0)
        _check_range("noise_sigma", self.noise_sigma, 0.0, 60.0)
        _check_range("lighting_gradient", self.lighting_gradient, 0.0, 0.95)
        _check_range("brightness", self.brightness, -128.0, 128.0)
        _check_range("contrast", self.contrast, 0.05, 4.0)
        _check_range("marker_black", self.marker_black, 0, 255)
        _check_range("marker_white", self.marker_white, 0, 255)
        if self.marker_black[1] >= self.marker_white[0]:
            raise SceneError("Effects.marker_black must stay below Effects.marker_white")

    @classmethod
    def clean(cls) -> Effects:
        """No effects: plain backgrounds, perfect ink, no blur or noise."""
        return cls()

    @classmethod
    def realistic(cls) -> Effects:
        """Moderate camera-like degradations and a cluttered background."""
        return cls(
            backgrounds=BACKGROUND_KINDS,
            clutter=(4, 20),
            blur_sigma=(0.0, 1.0),
            motion_blur_px=(0.0, 2.5),
            noise_sigma=(1.0, 5.0),
            lighting_gradient=(0.0, 0.45),
            brightness=(-25.0, 20.0),
            contrast=(0.75, 1.1),
            marker_black=(5, 45),
            marker_white=(190, 250),
        )

    @classmethod
    def harsh(cls) -> Effects:
        """Strong degradations: dark, low contrast, blurred and noisy."""
        return cls(
            backgrounds=BACKGROUND_KINDS,
            clutter=(10, 40),
            blur_sigma=(0.5, 2.0),
            motion_blur_px=(0.0, 6.0),
            noise_sigma=(4.0, 12.0),
            lighting_gradient=(0.2, 0.7),
            brightness=(-50.0, 10.0),
            contrast=(0.45, 0.9),
            marker_black=(20, 70),
            marker_white=(150, 230),
        )

    @classmethod
    def real_camera(cls) -> Effects:
        """What real cameras do, each at a random strength per scene: coloured light and white
        balance errors, under- and over-exposure, shadows and glare across tags, paper grain,
        greyscale (IR) frames, rolling shutter, strong blur and JPEG (quality 40-95, 4:2:0)."""
        return cls(
            backgrounds=BACKGROUND_KINDS,
            clutter=(4, 20),
            blur_sigma=(0.0, 2.0),
            motion_blur_px=(0.0, 12.0),
            noise_sigma=(1.0, 8.0),
            lighting_gradient=(0.0, 0.5),
            brightness=(-15.0, 15.0),
            contrast=(0.7, 1.1),
            marker_black=(5, 60),
            marker_white=(170, 250),
            camera=CameraEffects.real_camera(),
        )

    def sample(self, rng: np.random.Generator) -> EffectParams:
        """Draw one set of effect values."""

        def pick(rng_range: tuple[float, float]) -> float:
            low, high = rng_range
            return float(rng.uniform(low, high)) if high > low else float(low)

        return EffectParams(
            background=str(self.backgrounds[int(rng.integers(len(self.backgrounds)))]),
            clutter=int(rng.integers(self.clutter[0], self.clutter[1] + 1)),
            blur_sigma=pick(self.blur_sigma),
            motion_blur_px=pick(self.motion_blur_px),
            motion_angle_deg=float(rng.uniform(0.0, 180.0)),
            noise_sigma=pick(self.noise_sigma),
            lighting_gradient=pick(self.lighting_gradient),
            lighting_angle_deg=float(rng.uniform(0.0, 360.0)),
            brightness=pick(self.brightness),
            contrast=pick(self.contrast),
            # drawn last and only when enabled: without camera effects a scene draws exactly the
            # values it would if camera effects did not exist
            camera=self.camera.sample(rng) if self.camera.enabled else CameraParams(),
        )

    def ink(self, rng: np.random.Generator) -> tuple[int, int]:
        """Black and white levels of one printed marker."""
        black = int(rng.integers(self.marker_black[0], self.marker_black[1] + 1))
        white = int(rng.integers(self.marker_white[0], self.marker_white[1] + 1))
        return black, white

    def describe(self) -> dict[str, object]:
        """Plain mapping of the ranges (for reports)."""
        out: dict[str, object] = {f.name: getattr(self, f.name) for f in fields(self)}
        out["camera"] = self.camera.describe()
        return out


# --------------------------------------------------------------------------- backgrounds


def ramp_grid(width: int, height: int, angle_deg: float, step: int = 8) -> npt.NDArray[np.float32]:
    """Linear ramp 0..1 across a width x height image along `angle_deg`, sampled on a coarse
    grid (about one sample every `step` pixels, corners included); upsample with `stretch`."""
    gw, gh = max(2, math.ceil(width / step)), max(2, math.ceil(height / step))
    a = math.radians(angle_deg)
    xs = np.linspace(0.0, width - 1.0, gw, dtype=np.float32) * np.float32(math.cos(a))
    ys = np.linspace(0.0, height - 1.0, gh, dtype=np.float32) * np.float32(math.sin(a))
    r = np.add.outer(ys, xs)
    lo, hi = float(r.min()), float(r.max())
    if hi - lo < 1e-6:
        return np.zeros_like(r)
    out: npt.NDArray[np.float32] = (r - np.float32(lo)) * np.float32(1.0 / (hi - lo))
    return out


def stretch(image: npt.NDArray[np.uint8], width: int, height: int) -> npt.NDArray[np.uint8]:
    """Bilinear resize to width x height (for smooth fields computed on coarse grids)."""
    if image.shape[1] == width and image.shape[0] == height:
        return image
    return u8(cv2.resize(image, (width, height), interpolation=cv2.INTER_LINEAR))


def lowpass_noise(
    width: int, height: int, rng: np.random.Generator, scale_px: float, octaves: int = 3
) -> npt.NDArray[np.uint8]:
    """Smooth random texture (uint8, H x W, stretched to 0..255): octaves of upsampled noise,
    the coarsest with features about `scale_px` pixels wide, each next one 3x finer. Computed
    at a reduced resolution when even the finest octave is several pixels wide."""
    finest = max(scale_px, 1.0) / 3.0 ** (octaves - 1)
    factor = max(1, min(4, math.floor(finest / 2.0)))
    w, h = max(2, math.ceil(width / factor)), max(2, math.ceil(height / factor))
    acc = np.zeros((h, w), dtype=np.float32)
    cell = max(scale_px, 1.0) / factor
    weight = 1.0
    for _ in range(octaves):
        gw = max(2, math.ceil(w / cell) + 1)
        gh = max(2, math.ceil(h / cell) + 1)
        grid = rng.standard_normal((gh, gw), dtype=np.float32)
        up = cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        acc = np.asarray(cv2.scaleAdd(up, weight, acc), dtype=np.float32)
        cell = max(cell / 3.0, 1.0)
        weight *= 0.55
    lo, hi = float(acc.min()), float(acc.max())
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    small = u8(cv2.convertScaleAbs(acc, alpha=scale, beta=-lo * scale))
    return stretch(small, width, height)


def colourise(
    index: npt.NDArray[np.uint8], low: npt.ArrayLike, high: npt.ArrayLike
) -> npt.NDArray[np.uint8]:
    """Map a uint8 index image to BGR by linear interpolation between two colours."""
    t = np.linspace(0.0, 1.0, 256)[:, None]
    lo = np.asarray(low, dtype=np.float64).reshape(1, 3)
    hi = np.asarray(high, dtype=np.float64).reshape(1, 3)
    lut = np.clip(np.rint(lo + (hi - lo) * t), 0, 255).astype(np.uint8).reshape(1, 256, 3)
    bgr = u8(cv2.cvtColor(index, cv2.COLOR_GRAY2BGR))
    return u8(cv2.LUT(bgr, lut))


def solid(width: int, height: int, colour: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """A BGR image of one colour (cv2 fill: much faster than numpy broadcasting)."""
    c = np.clip(np.rint(np.asarray(colour, dtype=np.float64).reshape(3)), 0, 255)
    out = np.empty((height, width, 3), dtype=np.uint8)
    cv2.rectangle(out, (0, 0), (width - 1, height - 1), (float(c[0]), float(c[1]), float(c[2])), -1)
    return out


def draw_rocks(
    canvas: npt.NDArray[np.uint8],
    count: int,
    rng: np.random.Generator,
    size_px: tuple[float, float],
) -> None:
    """Scatter `count` soft-edged stones (filled ellipses in earthy grays) in place."""
    height, width = canvas.shape[:2]
    for _ in range(count):
        centre = (
            round(float(rng.uniform(0, width)) * 16),
            round(float(rng.uniform(0, height)) * 16),
        )
        a = float(rng.uniform(size_px[0], size_px[1])) / 2
        axes = (max(1, round(a * 16)), max(1, round(a * float(rng.uniform(0.4, 1.0)) * 16)))
        level = float(rng.uniform(40, 200))
        colour = tuple(float(v) for v in np.clip(level + rng.uniform(-12, 12, 3), 0, 255))
        cv2.ellipse(
            canvas, centre, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1, cv2.LINE_AA, 4
        )


def _random_colour(
    rng: np.random.Generator, low: float, high: float, tint: float
) -> npt.NDArray[np.float64]:
    base = rng.uniform(low, high)
    return np.clip(base + rng.uniform(-tint, tint, 3), 0, 255)


def background(
    kind: str, width: int, height: int, rng: np.random.Generator
) -> npt.NDArray[np.uint8]:
    """A BGR background of the given kind."""
    if kind == "plain":
        return solid(width, height, _random_colour(rng, 70, 235, 12))
    if kind == "gradient":
        t = ramp_grid(width, height, float(rng.uniform(0, 360)))
        index = u8(cv2.convertScaleAbs(t, alpha=255.0))
        low, high = _random_colour(rng, 40, 150, 15), _random_colour(rng, 150, 245, 15)
        return stretch(colourise(index, low, high), width, height)
    if kind == "textured":
        scale = float(rng.uniform(0.05, 0.25)) * min(width, height)
        index = lowpass_noise(width, height, rng, scale, octaves=4)
        return colourise(index, _random_colour(rng, 30, 110, 20), _random_colour(rng, 140, 230, 20))
    raise SceneError(f"unknown background kind {kind!r} (known: {BACKGROUND_KINDS})")


def _colour_tuple(rng: np.random.Generator) -> tuple[int, int, int]:
    c = rng.integers(0, 256, 3)
    return (int(c[0]), int(c[1]), int(c[2]))


def draw_clutter(
    canvas: npt.NDArray[np.uint8],
    count: int,
    rng: np.random.Generator,
    size: tuple[float, float] = (0.02, 0.2),
) -> None:
    """Draw `count` random shapes (rectangles, lines, circles, text, noise patches) in place,
    each about `size` (fraction of the shorter image side) wide."""
    height, width = canvas.shape[:2]
    short = min(width, height)
    for _ in range(count):
        kind = int(rng.integers(5))
        colour = _colour_tuple(rng)
        cx, cy = float(rng.uniform(0, width)), float(rng.uniform(0, height))
        size_px = float(rng.uniform(size[0], size[1])) * short
        if kind == 0:  # rotated rectangle, filled or outlined
            box = (
                (cx, cy),
                (size_px, size_px * float(rng.uniform(0.3, 1.5))),
                float(rng.uniform(0, 180)),
            )
            pts = np.rint(cv2.boxPoints(box) * 16).astype(np.int32)
            if rng.random() < 0.7:
                cv2.fillPoly(canvas, [pts], colour, cv2.LINE_AA, shift=4)
            else:
                thick = max(1, int(size_px * float(rng.uniform(0.02, 0.1))))
                cv2.polylines(canvas, [pts], True, colour, thick, cv2.LINE_AA, shift=4)
        elif kind == 1:  # line
            angle = float(rng.uniform(0, math.pi))
            dx, dy = math.cos(angle) * size_px * 2, math.sin(angle) * size_px * 2
            p0 = (round(cx - dx), round(cy - dy))
            p1 = (round(cx + dx), round(cy + dy))
            thick = max(1, int(rng.uniform(0.002, 0.015) * short))
            cv2.line(canvas, p0, p1, colour, thick, cv2.LINE_AA)
        elif kind == 2:  # ellipse / circle
            axes = (
                max(1, round(size_px / 2)),
                max(1, round(size_px / 2 * float(rng.uniform(0.4, 1.0)))),
            )
            thick = -1 if rng.random() < 0.6 else max(1, int(size_px * 0.08))
            cv2.ellipse(
                canvas,
                (round(cx), round(cy)),
                axes,
                float(rng.uniform(0, 180)),
                0,
                360,
                colour,
                thick,
                cv2.LINE_AA,
            )
        elif kind == 3:  # text
            letters = string.ascii_letters + string.digits
            n = int(rng.integers(2, 9))
            text = "".join(letters[int(i)] for i in rng.integers(len(letters), size=n))
            font = _FONTS[int(rng.integers(len(_FONTS)))]
            scale = size_px / 30.0
            thick = max(1, round(scale * 2))
            cv2.putText(
                canvas, text, (round(cx), round(cy)), font, scale, colour, thick, cv2.LINE_AA
            )
        else:  # textured noise patch
            pw = max(4, round(size_px * float(rng.uniform(0.7, 1.6))))
            ph = max(4, round(size_px * float(rng.uniform(0.7, 1.6))))
            x0, y0 = int(cx), int(cy)
            x1, y1 = min(width, x0 + pw), min(height, y0 + ph)
            if x1 - x0 < 2 or y1 - y0 < 2:
                continue
            index = lowpass_noise(x1 - x0, y1 - y0, rng, float(rng.uniform(2, 12)), octaves=2)
            lo = _random_colour(rng, 0, 128, 30)
            hi = _random_colour(rng, 128, 255, 30)
            canvas[y0:y1, x0:x1] = colourise(index, lo, hi)


# --------------------------------------------------------------------------- image effects


def _motion_kernel(length: float, angle_deg: float) -> npt.NDArray[np.float32]:
    size = 2 * math.ceil(length / 2) + 1
    sup = 8
    big = np.zeros((size * sup, size * sup), dtype=np.float32)
    c = (size * sup - 1) / 2.0
    a = math.radians(angle_deg)
    dx, dy = math.cos(a) * length * sup / 2, math.sin(a) * length * sup / 2
    p0 = (round((c - dx) * 16), round((c - dy) * 16))
    p1 = (round((c + dx) * 16), round((c + dy) * 16))
    cv2.line(big, p0, p1, 1.0, sup, cv2.LINE_AA, shift=4)
    kernel = np.asarray(cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA), np.float32)
    total = float(kernel.sum())
    if total <= 0:
        kernel[size // 2, size // 2] = 1.0
        return kernel
    return kernel / np.float32(total)


def apply_effects(
    image: npt.NDArray[np.uint8], params: EffectParams, rng: np.random.Generator
) -> npt.NDArray[np.uint8]:
    """Lighting, brightness/contrast, blur, motion blur and noise on a BGR image (new array)."""
    out = image
    height, width = out.shape[:2]
    if params.lighting_gradient > 1e-3:
        gain = ramp_grid(width, height, params.lighting_angle_deg)
        gain8 = u8(cv2.convertScaleAbs(gain, alpha=-255.0 * params.lighting_gradient, beta=255.0))
        gain3 = stretch(u8(cv2.cvtColor(gain8, cv2.COLOR_GRAY2BGR)), width, height)
        out = u8(cv2.multiply(out, gain3, scale=1.0 / 255.0))
    if abs(params.contrast - 1.0) > 1e-3 or abs(params.brightness) > 1e-3:
        offset = 128.0 * (1.0 - params.contrast) + params.brightness
        levels = np.arange(256, dtype=np.float64) * params.contrast + offset
        out = u8(cv2.LUT(out, np.clip(np.rint(levels), 0, 255).astype(np.uint8)))
    if params.blur_sigma > 0.05:
        out = u8(cv2.GaussianBlur(out, (0, 0), params.blur_sigma))
    if params.motion_blur_px >= 1.0:
        kernel = _motion_kernel(params.motion_blur_px, params.motion_angle_deg)
        out = u8(cv2.filter2D(out, -1, kernel, borderType=cv2.BORDER_REFLECT))
    if params.noise_sigma > 0.05:
        table = np.rint(_UNIT_NORMAL_LEVELS * params.noise_sigma).astype(np.int16).reshape(1, 256)
        count = out.size
        raw = rng.bit_generator.random_raw((count + 7) // 8).view(np.uint8)
        index = raw[:count].reshape(out.shape)
        noise = cv2.LUT(index, table)
        out = u8(cv2.add(out, noise, dtype=cv2.CV_8U))
    if out is image:
        out = image.copy()
    return out
