"""What real cameras add to a scene: coloured light and white balance errors, exposure and tone,
shadows and glare across tags, paper texture, greyscale / IR sensors, rolling shutter and JPEG.

`CameraEffects` holds the ranges (it is `Effects.camera`), `CameraParams` the values drawn for
one scene. Everything is off by default, and while it is off nothing here draws a random number
or touches a pixel, so scenes of the presets without camera effects do not depend on this module.
While it is on, the number of random draws does not depend on which options are set, so one
seed gives the same layout (tags, poses, background) whatever camera effects are chosen.

Order inside a frame, following the light from the scene to the file (`SceneGenerator`):

1. on each printed tag: paper texture, then a shadow and a glare blob across it (`light_scene`);
2. the colour of the light and the camera's white balance: per-channel gains (`light_scene`);
3. the readout: a rolling shutter shifts rows progressively (`rolling_shutter`; the truth
   corners are sheared with the image by `shear_points`);
4. `_effects.apply_effects`: lighting gradient, contrast, blur, motion blur, sensor noise;
5. processing (`camera_output`): exposure, black level and gamma, greyscale sensor, JPEG.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._raster import u8

#: Kinds of coloured light understood by `CameraEffects.cast_kinds`; "white_balance" is a random
#: per-channel error of the camera's white balance rather than a named light.
CAST_KINDS: tuple[str, ...] = ("tungsten", "blue_led", "green_fluorescent", "white_balance")

# B, G, R gains of each light at full strength, seen by a camera balanced for daylight.
_CAST_GAINS: dict[str, tuple[float, float, float]] = {
    "tungsten": (0.45, 0.95, 1.45),
    "blue_led": (1.5, 0.95, 0.5),
    "green_fluorescent": (0.7, 1.25, 0.65),
}
# Largest gain (or inverse gain) of one channel under a full-strength white balance error.
_WHITE_BALANCE_ERROR = 1.6

# Uniform numbers drawn per scene and per tag while camera effects are on (fixed counts, so the
# stream of random numbers is the same whatever options are set).
_SCENE_DRAWS = 20
_TAG_DRAWS = 16

# Light kinds drawn on tags, in drawing order: the paper, then shadows, then specular glare.
_LIGHT_ORDER = {"paper": 0, "shadow": 1, "glare": 2}
_SHIFT = 4  # sub-pixel bits of cv2 drawing


def _check_range(name: str, value: tuple[float, float], low: float, high: float) -> None:
    if len(value) != 2 or not (low <= value[0] <= value[1] <= high):
        raise SceneError(
            f"CameraEffects.{name} must be (min, max) within [{low}, {high}], got {value}"
        )


def _check_probability(name: str, value: float) -> None:
    if not 0.0 <= value <= 1.0:
        raise SceneError(f"CameraEffects.{name} must be in [0, 1], got {value}")


@dataclass(frozen=True)
class CameraParams:
    """Camera effect values drawn for one scene (or one drive) from `CameraEffects`.

    enabled: camera effects are on (False: none of the others is applied). channel_gains: B, G,
    R gains of the light (`cast` names its kind). exposure_stops, black_crush, gamma: the tone
    curve (see `tone_curve`). shadow_* / glare_*: chance per tag, and strength, of a shadow or a
    glare blob across it; shadow_softness is the blur of the shadow's edge as a fraction of the
    tag side. stripes_*: chance per tag of hard light stripes across it and its surround (sun
    through blinds), the light the shadowed stripes block, and the stripes' period as a
    fraction of the tag side. paper_texture: std of the paper's grain on white, grey levels.
    greyscale: a monochrome (IR) sensor, output mono_offset + mono_contrast * luma on all three
    channels.
    rolling_shutter_px: horizontal shift of the bottom row relative to the top row.
    jpeg_quality: 0 (no compression) or the JPEG quality, 4:2:0 chroma subsampling.
    """

    enabled: bool = False
    channel_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    cast: str = "none"
    exposure_stops: float = 0.0
    black_crush: float = 0.0
    gamma: float = 1.0
    shadow_probability: float = 0.0
    shadow_depth: float = 0.0
    shadow_softness: float = 0.0
    glare_probability: float = 0.0
    glare_strength: float = 0.0
    stripes_probability: float = 0.0
    stripes_depth: float = 0.0
    stripes_period: float = 0.0
    paper_texture: float = 0.0
    greyscale: bool = False
    mono_contrast: float = 1.0
    mono_offset: float = 0.0
    rolling_shutter_px: float = 0.0
    jpeg_quality: int = 0


@dataclass(frozen=True)
class CameraEffects:
    """Ranges of the camera effects: each (min, max) range is sampled uniformly per scene (per
    drive for `SceneGenerator.drive`), each probability is a per-scene or per-tag chance. The
    defaults turn everything off.

    - colour_cast: strength 0..1 of a light drawn from `cast_kinds` (gains interpolated
      geometrically from 1 to the light's full-strength gains).
    - exposure_stops: gain 2**stops before clipping (over-exposure clips highlights).
    - black_crush: fraction of the range below which levels are crushed to black.
    - gamma: exponent of the tone curve on levels 0..1 (> 1 darkens mid tones).
    - shadow_probability / shadow_depth / shadow_softness: chance per tag of a shadow band
      crossing it, fraction of light it blocks, blur of its edge (fraction of the tag side).
    - glare_probability / glare_strength: chance per tag of a specular blob partly over it,
      blend towards white at its core.
    - stripes_probability / stripes_depth / stripes_period: chance per tag of hard-edged
      parallel stripes of shadow across it and the paper around it (sun through blinds, a
      railing's shadow), the fraction of light the shadowed stripes block, and the period of
      the stripes as a fraction of the tag side.
    - paper_texture: grain of the printed paper, std in grey levels on white (multiplicative;
      drawn afresh each frame, while a drive's shadows and glare stay put on their tags).
    - greyscale_probability / mono_contrast / mono_offset: chance of a monochrome (IR) frame and
      its gain and grey offset (low contrast, lifted blacks).
    - rolling_shutter_px: magnitude of the shift of the bottom row relative to the top one
      (direction random per scene).
    - jpeg_quality: (0, 0) for none, else quality range within 1..100 (4:2:0 subsampling).
    """

    colour_cast: tuple[float, float] = (0.0, 0.0)
    cast_kinds: tuple[str, ...] = CAST_KINDS
    exposure_stops: tuple[float, float] = (0.0, 0.0)
    black_crush: tuple[float, float] = (0.0, 0.0)
    gamma: tuple[float, float] = (1.0, 1.0)
    shadow_probability: float = 0.0
    shadow_depth: tuple[float, float] = (0.0, 0.0)
    shadow_softness: tuple[float, float] = (0.0, 0.0)
    glare_probability: float = 0.0
    glare_strength: tuple[float, float] = (0.0, 0.0)
    stripes_probability: float = 0.0
    stripes_depth: tuple[float, float] = (0.0, 0.0)
    stripes_period: tuple[float, float] = (0.3, 1.0)
    paper_texture: tuple[float, float] = (0.0, 0.0)
    greyscale_probability: float = 0.0
    mono_contrast: tuple[float, float] = (1.0, 1.0)
    mono_offset: tuple[float, float] = (0.0, 0.0)
    rolling_shutter_px: tuple[float, float] = (0.0, 0.0)
    jpeg_quality: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        if not self.cast_kinds or any(k not in CAST_KINDS for k in self.cast_kinds):
            raise SceneError(
                f"CameraEffects.cast_kinds must be a non-empty subset of {CAST_KINDS}, "
                f"got {self.cast_kinds!r}"
            )
        _check_range("colour_cast", self.colour_cast, 0.0, 1.0)
        _check_range("exposure_stops", self.exposure_stops, -4.0, 4.0)
        _check_range("black_crush", self.black_crush, 0.0, 0.6)
        _check_range("gamma", self.gamma, 0.25, 4.0)
        _check_range("shadow_depth", self.shadow_depth, 0.0, 0.95)
        _check_range("shadow_softness", self.shadow_softness, 0.0, 1.0)
        _check_range("glare_strength", self.glare_strength, 0.0, 1.0)
        _check_range("stripes_depth", self.stripes_depth, 0.0, 0.95)
        _check_range("stripes_period", self.stripes_period, 0.1, 4.0)
        _check_range("paper_texture", self.paper_texture, 0.0, 40.0)
        _check_range("mono_contrast", self.mono_contrast, 0.05, 2.0)
        _check_range("mono_offset", self.mono_offset, 0.0, 200.0)
        _check_range("rolling_shutter_px", self.rolling_shutter_px, 0.0, 200.0)
        probabilities = ("shadow_probability", "glare_probability", "stripes_probability")
        for name in (*probabilities, "greyscale_probability"):
            _check_probability(name, getattr(self, name))
        if self.jpeg_quality != (0, 0):
            _check_range("jpeg_quality", self.jpeg_quality, 1, 100)

    @classmethod
    def real_camera(cls) -> CameraEffects:
        """Everything on, with strengths that real cameras reach (used by
        `Effects.real_camera`)."""
        return cls(
            colour_cast=(0.0, 1.0),
            exposure_stops=(-1.5, 1.0),
            black_crush=(0.0, 0.15),
            gamma=(0.7, 1.5),
            shadow_probability=0.35,
            shadow_depth=(0.3, 0.8),
            shadow_softness=(0.0, 0.3),
            glare_probability=0.25,
            glare_strength=(0.3, 1.0),
            paper_texture=(0.0, 8.0),
            greyscale_probability=0.2,
            mono_contrast=(0.4, 1.0),
            mono_offset=(0.0, 60.0),
            rolling_shutter_px=(0.0, 25.0),
            jpeg_quality=(40, 95),
        )

    @property
    def enabled(self) -> bool:
        """Whether any camera effect is asked for."""
        return self != CameraEffects()

    def sample(self, rng: np.random.Generator) -> CameraParams:
        """Draw one set of values (always the same number of random draws)."""
        u = rng.random(_SCENE_DRAWS)

        def pick(i: int, rng_range: tuple[float, float]) -> float:
            low, high = rng_range
            return float(low + (high - low) * u[i])

        kind = self.cast_kinds[min(int(u[0] * len(self.cast_kinds)), len(self.cast_kinds) - 1)]
        strength = pick(1, self.colour_cast)
        if kind == "white_balance":
            log_error = math.log(_WHITE_BALANCE_ERROR)
            full = tuple(math.exp(log_error * (2.0 * float(v) - 1.0)) for v in u[2:5])
        else:
            full = _CAST_GAINS[kind]
        gains = (full[0] ** strength, full[1] ** strength, full[2] ** strength)
        shear = pick(13, self.rolling_shutter_px) * (1.0 if u[14] < 0.5 else -1.0)
        low_q, high_q = self.jpeg_quality
        quality = min(high_q, low_q + int(u[15] * (high_q - low_q + 1)))
        return CameraParams(
            enabled=self.enabled,
            channel_gains=gains,
            cast=kind if strength > 0.0 else "none",
            exposure_stops=pick(5, self.exposure_stops),
            black_crush=pick(6, self.black_crush),
            gamma=pick(7, self.gamma),
            shadow_probability=self.shadow_probability,
            shadow_depth=pick(8, self.shadow_depth),
            shadow_softness=pick(9, self.shadow_softness),
            glare_probability=self.glare_probability,
            glare_strength=pick(10, self.glare_strength),
            stripes_probability=self.stripes_probability,
            stripes_depth=pick(18, self.stripes_depth),
            stripes_period=pick(19, self.stripes_period),
            paper_texture=pick(11, self.paper_texture),
            greyscale=bool(u[12] < self.greyscale_probability),
            mono_contrast=pick(16, self.mono_contrast),
            mono_offset=pick(17, self.mono_offset),
            rolling_shutter_px=shear,
            jpeg_quality=quality,
        )

    def describe(self) -> dict[str, object]:
        """Plain mapping of the ranges (for reports)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


# --------------------------------------------------------------------------- light on tags


@dataclass(frozen=True)
class Light:
    """One patch of light on the scene: `kind` "paper" (grain over the polygon), "shadow"
    (darkens by `amount`) or "glare" (blends towards white by `amount`); `polygon` (N, 2) in
    image coordinates, its edge blurred with a Gaussian of `sigma_px`."""

    kind: str
    polygon: npt.NDArray[np.float64]
    amount: float
    sigma_px: float


def _ellipse(
    centre: npt.NDArray[np.float64], a: float, b: float, angle: float
) -> npt.NDArray[np.float64]:
    t = np.linspace(0.0, 2.0 * math.pi, 48, endpoint=False)
    c, s = math.cos(angle), math.sin(angle)
    x, y = a * np.cos(t), b * np.sin(t)
    out: npt.NDArray[np.float64] = centre + np.stack([c * x - s * y, s * x + c * y], axis=1)
    return out


def plan_tag_light(
    params: CameraParams,
    corners: npt.NDArray[np.float64],
    footprint: npt.NDArray[np.float64],
    rng: np.random.Generator,
) -> list[Light]:
    """Paper grain over a tag's `footprint` (quiet zone included) and, by chance, a shadow and
    a glare blob across its `corners`. The shapes are drawn relative to the tag from a fixed
    number of draws of `rng` (a drive passes each tag's own generator, so they follow the tag
    from frame to frame)."""
    u = rng.random(_TAG_DRAWS)
    lights: list[Light] = []
    if params.paper_texture > 0.0:
        lights.append(Light("paper", footprint, params.paper_texture, 0.0))
    side = float(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1).mean())
    if u[0] < params.shadow_probability and params.shadow_depth > 0.0:
        # a band whose near edge passes through a point inside the tag, at any angle; its far
        # edge (slanted) lies 0.3 to 3 sides away, so it covers part of the tag or all beyond
        a, b = 0.25 + 0.5 * u[1], 0.25 + 0.5 * u[2]
        top = corners[0] + (corners[1] - corners[0]) * a
        bottom = corners[3] + (corners[2] - corners[3]) * a
        anchor = top + (bottom - top) * b
        theta = 2.0 * math.pi * float(u[3])
        normal = np.array([math.cos(theta), math.sin(theta)])
        along = np.array([-normal[1], normal[0]]) * side * (1.5 + 2.5 * float(u[4]))
        far_a = side * (0.3 + 2.7 * float(u[5]))
        far_b = side * (0.3 + 2.7 * float(u[6]))
        polygon = np.stack(
            [
                anchor - along,
                anchor + along,
                anchor + along + normal * far_a,
                anchor - along + normal * far_b,
            ]
        )
        sigma = params.shadow_softness * side
        lights.append(Light("shadow", polygon, params.shadow_depth, sigma))
    if u[7] < params.glare_probability and params.glare_strength > 0.0:
        # an elliptic highlight whose centre is within 0.6 of its smaller radius of a point of
        # the tag's outline, so it always lies partly over the tag and partly beside it
        k = min(int(u[8] * 4), 3)
        edge_point = corners[k] + (corners[(k + 1) % 4] - corners[k]) * (0.1 + 0.8 * u[9])
        inward = corners.mean(axis=0) - edge_point
        major = side * (0.12 + 0.28 * float(u[11]))
        minor = major * (0.4 + 0.6 * float(u[12]))
        offset = minor * (1.2 * float(u[10]) - 0.6) / max(float(np.linalg.norm(inward)), 1e-9)
        polygon = _ellipse(edge_point + inward * offset, major, minor, math.pi * float(u[13]))
        lights.append(Light("glare", polygon, params.glare_strength, 0.5 * minor))
    if u[14] < params.stripes_probability and params.stripes_depth > 0.0:
        lights += _stripes(params, corners, side, np.random.default_rng(int(u[15] * 2**32)))
    return lights


def _stripes(
    params: CameraParams,
    corners: npt.NDArray[np.float64],
    side: float,
    rng: np.random.Generator,
) -> list[Light]:
    """Hard-edged parallel shadow stripes over a tag and 1.5 sides around it, at a random
    angle and phase, each dark for 30-70 % of the period (``rng``: the tag's own draws)."""
    u = rng.random(3)
    theta = math.pi * float(u[0])
    normal = np.array([math.cos(theta), math.sin(theta)])
    along = np.array([-normal[1], normal[0]])
    period = max(params.stripes_period * side, 2.0)
    dark = period * (0.3 + 0.4 * float(u[1]))
    reach = 2.0 * side  # the stripes cover the tag and the paper around it
    centre = corners.mean(axis=0)
    lights = []
    offset = -reach + period * float(u[2])
    while offset < reach:
        near, far = centre + normal * offset, centre + normal * (offset + dark)
        polygon = np.stack(
            [near - along * reach, near + along * reach, far + along * reach, far - along * reach]
        )
        lights.append(Light("shadow", polygon, params.stripes_depth, min(1.0, 0.01 * side)))
        offset += period
    return lights


def _mask(
    polygon: npt.NDArray[np.float64], sigma: float, width: int, height: int
) -> tuple[npt.NDArray[np.float32], tuple[int, int, int, int]] | None:
    """Coverage 0..1 of a polygon with its edge blurred by `sigma`, over the part of the image
    it can reach: (mask, (x0, y0, x1, y1)), or None when that is empty. Wide blurs are done on
    a grid `step` times coarser and stretched back (smooth anyway at that scale)."""
    pad = 3.0 * sigma + 2.0
    x0 = max(0, math.floor(float(polygon[:, 0].min()) - pad))
    y0 = max(0, math.floor(float(polygon[:, 1].min()) - pad))
    x1 = min(width, math.ceil(float(polygon[:, 0].max()) + pad) + 1)
    y1 = min(height, math.ceil(float(polygon[:, 1].max()) + pad) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    step = max(1, min(8, math.floor(sigma / 2.0)))
    w, h = math.ceil((x1 - x0) / step), math.ceil((y1 - y0) / step)
    mask = np.zeros((h, w), dtype=np.float32)
    # pixel (r, c) of the coarse grid covers fine pixels [c * step, (c + 1) * step)
    offset = np.array([x0 - 0.5 + step / 2.0, y0 - 0.5 + step / 2.0])
    pts = np.rint((polygon - offset) / step * (1 << _SHIFT)).astype(np.int32)
    cv2.fillPoly(mask, [pts], 1.0, cv2.LINE_AA, shift=_SHIFT)
    if sigma > 0.3:
        mask = np.asarray(cv2.GaussianBlur(mask, (0, 0), sigma / step), dtype=np.float32)
    if step > 1:
        mask = np.asarray(cv2.resize(mask, (w * step, h * step)), dtype=np.float32)
        mask = np.ascontiguousarray(mask[: y1 - y0, : x1 - x0])
    return mask, (x0, y0, x1, y1)


def _grain(width: int, height: int, rng: np.random.Generator) -> npt.NDArray[np.float32]:
    """Fine noise of unit std with features about a pixel wide (paper fibres)."""
    raw = rng.standard_normal((height, width), dtype=np.float32)
    smooth = np.asarray(cv2.GaussianBlur(raw, (0, 0), 0.8), dtype=np.float32)
    std = float(smooth.std())
    out: npt.NDArray[np.float32] = smooth / np.float32(std if std > 0 else 1.0)
    return out


def light_scene(
    image: npt.NDArray[np.uint8],
    params: CameraParams,
    lights: list[Light],
    rng: np.random.Generator,
) -> npt.NDArray[np.uint8]:
    """Paper grain, shadows and glare (`plan_tag_light`), then the light's colour
    (`colour_cast`), on a BGR image (a new array; one draw of `rng`)."""
    grain_rng = np.random.default_rng(int(rng.integers(2**63)))
    height, width = image.shape[:2]
    lit = image.copy()
    for light in sorted(lights, key=lambda item: _LIGHT_ORDER[item.kind]):
        found = _mask(light.polygon, light.sigma_px, width, height)
        if found is None:
            continue
        mask, (x0, y0, x1, y1) = found
        roi = lit[y0:y1, x0:x1].astype(np.float32)
        if light.kind == "paper":
            grain = _grain(x1 - x0, y1 - y0, grain_rng)
            roi *= (1.0 + mask * grain * np.float32(light.amount / 255.0))[:, :, None]
        elif light.kind == "shadow":
            roi *= (1.0 - mask * np.float32(light.amount))[:, :, None]
        else:
            alpha = np.minimum(mask * np.float32(1.5), np.float32(1.0)) * np.float32(light.amount)
            roi += alpha[:, :, None] * (np.float32(255.0) - roi)
        lit[y0:y1, x0:x1] = np.clip(np.rint(roi), 0, 255)
    return colour_cast(lit, params.channel_gains)


def colour_cast(
    image: npt.NDArray[np.uint8], gains: tuple[float, float, float]
) -> npt.NDArray[np.uint8]:
    """Per-channel gains (B, G, R) on a BGR image, clipped at 255 (a new array)."""
    levels = np.arange(256, dtype=np.float64)[:, None] * np.asarray(gains, dtype=np.float64)
    lut = np.clip(np.rint(levels), 0, 255).astype(np.uint8).reshape(256, 1, 3)
    return u8(cv2.LUT(image, lut))


# --------------------------------------------------------------------------- readout


def shear_points(points: npt.ArrayLike, shift_px: float, height: int) -> npt.NDArray[np.float64]:
    """Where `rolling_shutter(image, shift_px)` moves image points (N, 2): right by `shift_px`
    times the row's offset from the middle row, as a fraction of the image height."""
    pts = np.array(points, dtype=np.float64).reshape(-1, 2)
    pts[:, 0] += shift_px * (pts[:, 1] - (height - 1) / 2.0) / max(height - 1, 1)
    return pts


def rolling_shutter(image: npt.NDArray[np.uint8], shift_px: float) -> npt.NDArray[np.uint8]:
    """Rows read one after another while the camera pans: each row is shifted horizontally in
    proportion to its distance from the middle row, the bottom row by `shift_px` relative to
    the top one (bilinear, edges replicated). Returns `image` itself when the shift is nil."""
    height, width = image.shape[:2]
    if abs(shift_px) < 1e-3:
        return image
    k = shift_px / max(height - 1, 1)
    matrix = np.array([[1.0, k, -k * (height - 1) / 2.0], [0.0, 1.0, 0.0]])
    return u8(
        cv2.warpAffine(
            image,
            matrix,
            (width, height),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
    )


# --------------------------------------------------------------------------- processing


def tone_curve(exposure_stops: float, black_crush: float, gamma: float) -> npt.NDArray[np.uint8]:
    """Lookup table (256,) of the camera's tone: level v in 0..1 becomes
    clip((v * 2**exposure_stops - black_crush) / (1 - black_crush), 0, 1) ** gamma."""
    v = np.arange(256, dtype=np.float64) / 255.0
    lifted = (v * 2.0**exposure_stops - black_crush) / (1.0 - black_crush)
    out = np.clip(lifted, 0.0, 1.0) ** gamma
    return u8(np.clip(np.rint(out * 255.0), 0, 255))


def to_mono(image: npt.NDArray[np.uint8], contrast: float, offset: float) -> npt.NDArray[np.uint8]:
    """What a monochrome (IR) sensor gives: offset + contrast * luma, the same on B, G and R."""
    luma = u8(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    levels = np.arange(256, dtype=np.float64) * contrast + offset
    mono = u8(cv2.LUT(luma, np.clip(np.rint(levels), 0, 255).astype(np.uint8)))
    return u8(cv2.cvtColor(mono, cv2.COLOR_GRAY2BGR))


def jpeg(
    image: npt.NDArray[np.uint8], quality: int, *, grey: bool = False
) -> npt.NDArray[np.uint8]:
    """Encode as JPEG at `quality` with 4:2:0 chroma subsampling and decode (a new BGR array).
    With `grey` (all channels equal) one luma plane is coded, as a monochrome camera does."""
    options = [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)]
    sampling = getattr(cv2, "IMWRITE_JPEG_SAMPLING_FACTOR", None)
    sampling_420 = getattr(cv2, "IMWRITE_JPEG_SAMPLING_FACTOR_420", None)
    if sampling is not None and sampling_420 is not None:
        options += [int(sampling), int(sampling_420)]  # (libjpeg's default anyway)
    source = np.ascontiguousarray(image[:, :, 0]) if grey else image
    ok, data = cv2.imencode(".jpg", source, options)
    if not ok:  # pragma: no cover - only on a broken OpenCV build
        raise SceneError("JPEG encoding failed")
    if grey:
        plane = u8(cv2.imdecode(data, cv2.IMREAD_GRAYSCALE))
        return u8(cv2.cvtColor(plane, cv2.COLOR_GRAY2BGR))
    return u8(cv2.imdecode(data, cv2.IMREAD_COLOR))


def camera_output(image: npt.NDArray[np.uint8], params: CameraParams) -> npt.NDArray[np.uint8]:
    """Tone curve, greyscale sensor and JPEG on a BGR image (a new array)."""
    curve = tone_curve(params.exposure_stops, params.black_crush, params.gamma)
    out = u8(cv2.LUT(image, curve))
    if params.greyscale:
        out = to_mono(out, params.mono_contrast, params.mono_offset)
    if params.jpeg_quality > 0:
        out = jpeg(out, params.jpeg_quality, grey=params.greyscale)
    return out
