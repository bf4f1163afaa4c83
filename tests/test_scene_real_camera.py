"""What real cameras add to synthetic scenes (`CameraEffects`, `Effects.real_camera`), tag sizes
in pixels, every dictionary family, and the default detector against OpenCV's on such frames."""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Sequence

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception.detect.types import Detection
from zenoh_perception.scene import (
    CAST_KINDS,
    CameraEffects,
    CameraModel,
    CameraParams,
    Effects,
    MarkerPose,
    Scene,
    SceneError,
    SceneGenerator,
)
from zenoh_perception.scene._camera_effects import (
    colour_cast,
    jpeg,
    shear_points,
    tone_curve,
)

Image = npt.NDArray[np.uint8]
Floats = npt.NDArray[np.float64]

# On, but with every strength at zero: draws the same random numbers as any other camera
# configuration (so scenes share their layout and background with it) and changes no pixel.
_NEUTRAL = CameraEffects(shadow_probability=1.0)
# A still camera on a plain background, ink levels 30 and 230 (neither clips when an effect
# adds or takes light): only the effect under test acts.
_STILL = Effects(marker_black=(30, 30), marker_white=(230, 230))
_SMALL = CameraModel(320, 240, 300.0, 300.0, 159.5, 119.5)

_DICTIONARIES = (
    "DICT_4X4_50",
    "DICT_5X5_100",
    "DICT_6X6_250",
    "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h11",
    "DICT_ARUCO_MIP_36h12",
)


def _with(camera: CameraEffects, base: Effects = _STILL) -> Effects:
    return dataclasses.replace(base, camera=camera)


def _facing_scene(
    camera: CameraEffects, *, seed: int = 0, base: Effects = _STILL, cam: CameraModel = _SMALL
) -> Scene:
    """One upright tag facing the camera, about 0.55 of the image height, in the middle."""
    gen = SceneGenerator(cam, seed=seed, effects=_with(camera, base))
    size = 0.55 * cam.height / cam.fy  # at 1 m
    return gen.scene_from_poses([MarkerPose(7, size, (0.0, 0.0, 1.0))])


def _f(image: Image) -> Floats:
    return image[:, :, :3].astype(np.float64)


def _inside(quad: Floats, shape: tuple[int, ...], grow: float = 1.0) -> npt.NDArray[np.bool_]:
    """Pixels whose centre lies in `quad` scaled by `grow` about its centre."""
    centre = quad.mean(axis=0)
    scaled = centre + (quad - centre) * grow
    mask = np.zeros(shape[:2], dtype=np.uint8)
    cv2.fillPoly(mask, [np.rint(scaled * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
    return mask.astype(bool)


# ------------------------------------------------------------------ options and preset


def test_existing_presets_leave_camera_effects_off() -> None:
    for effects in (Effects(), Effects.clean(), Effects.realistic(), Effects.harsh()):
        assert not effects.camera.enabled
        assert effects.sample(np.random.default_rng(0)).camera == CameraParams()
    real = Effects.real_camera()
    assert real.camera.enabled
    assert real.camera.jpeg_quality == (40, 95)
    assert real.motion_blur_px[1] >= 10.0  # strong motion blur is part of it
    assert set(real.camera.cast_kinds) == set(CAST_KINDS)
    assert isinstance(real.describe()["camera"], dict)


def test_real_camera_draws_every_effect_at_varying_strengths() -> None:
    rng = np.random.default_rng(1)
    drawn = [Effects.real_camera().sample(rng).camera for _ in range(200)]
    assert all(p.enabled for p in drawn)
    assert {p.cast for p in drawn} >= {"tungsten", "blue_led", "green_fluorescent"}
    assert 0.1 < np.mean([p.greyscale for p in drawn]) < 0.35
    shifts = [p.rolling_shutter_px for p in drawn]  # both directions
    assert min(shifts) < -10.0 and max(shifts) > 10.0
    qualities = [p.jpeg_quality for p in drawn]
    assert min(qualities) < 45 and max(qualities) > 90 and 40 <= min(qualities) <= max(qualities)
    stops = [p.exposure_stops for p in drawn]
    assert min(stops) < -1.0 and max(stops) > 0.5
    assert len({round(p.shadow_depth, 3) for p in drawn}) > 100  # a new strength per scene


def test_camera_effects_reject_bad_ranges() -> None:
    bad = [
        {"colour_cast": (0.5, 0.2)},
        {"colour_cast": (0.0, 1.5)},
        {"cast_kinds": ("sodium",)},
        {"cast_kinds": ()},
        {"jpeg_quality": (0, 50)},
        {"jpeg_quality": (50, 101)},
        {"gamma": (0.0, 1.0)},
        {"shadow_probability": 1.5},
        {"rolling_shutter_px": (-1.0, 1.0)},
    ]
    for kwargs in bad:
        with pytest.raises(SceneError):
            CameraEffects(**kwargs)  # type: ignore[arg-type]
    gen = SceneGenerator(_SMALL)
    with pytest.raises(SceneError):
        gen.random_scene(1, side_px=(20.0, 10.0))


def test_one_seed_gives_one_layout_whatever_the_camera_effects() -> None:
    cam = CameraModel.named("VGA")

    def scene(camera: CameraEffects) -> Scene:
        gen = SceneGenerator(cam, seed=4, effects=_with(camera, Effects.realistic()))
        return gen.random_scene(3, 2)

    neutral, real = scene(_NEUTRAL), scene(CameraEffects.real_camera())
    assert neutral.ids == real.ids
    for a, b in zip(neutral.markers, real.markers, strict=True):
        assert np.array_equal(a.tvec, b.tvec) and np.array_equal(a.rvec, b.rvec)
    assert not np.array_equal(neutral.image, real.image)
    # strengths of zero change no pixel, whichever option carries them
    glare_off = scene(CameraEffects(glare_probability=1.0))
    assert np.array_equal(neutral.image, glare_off.image)


# ------------------------------------------------------------------ colour casts


@settings(max_examples=20, deadline=None)
@given(gains=st.tuples(*[st.floats(0.4, 1.6)] * 3))
def test_colour_gains_move_each_channel_their_way(gains: tuple[float, float, float]) -> None:
    neutral = _facing_scene(_NEUTRAL).image[:, :, :3]
    cast = colour_cast(neutral, gains)
    before, after = _f(neutral).mean(axis=(0, 1)), cast.astype(np.float64).mean(axis=(0, 1))
    for channel, gain in enumerate(gains):
        if gain > 1.02:
            assert after[channel] > before[channel]
        elif gain < 0.98:
            assert after[channel] < before[channel]
        # unclipped levels are scaled exactly
        dark = neutral[:, :, channel] < 100
        expected = np.rint(neutral[:, :, channel][dark] * gain)
        assert np.abs(cast[:, :, channel][dark] - expected).max() <= 1


@pytest.mark.parametrize(
    ("kind", "strong", "weak"),
    [("tungsten", 2, 0), ("blue_led", 0, 2), ("green_fluorescent", 1, 2)],
)
def test_coloured_light_tints_the_frame(kind: str, strong: int, weak: int) -> None:
    camera = CameraEffects(colour_cast=(1.0, 1.0), cast_kinds=(kind,))
    scene = _facing_scene(camera)
    assert scene.effects.camera.cast == kind
    neutral = _f(_facing_scene(_NEUTRAL).image).mean(axis=(0, 1))
    tinted = _f(scene.image).mean(axis=(0, 1))
    # the light's dominant channel gains on its weakest one by a clear margin
    assert tinted[strong] / tinted[weak] > 1.4 * neutral[strong] / neutral[weak]


# ------------------------------------------------------------------ JPEG


def _stripes() -> Image:
    """Alternating red and blue columns: all the detail is in the chroma."""
    image = np.zeros((64, 64, 3), dtype=np.uint8)
    image[:, 0::2] = (40, 40, 200)
    image[:, 1::2] = (200, 40, 40)
    return image


def _encode_444(image: Image, quality: int) -> Image:
    """JPEG round trip with full-resolution chroma (4:4:4), for comparison."""
    options = [cv2.IMWRITE_JPEG_QUALITY, quality]
    options += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
    ok, data = cv2.imencode(".jpg", image, options)
    assert ok
    return np.asarray(cv2.imdecode(data, cv2.IMREAD_COLOR), dtype=np.uint8)


def _chroma_detail(image: Image) -> float:
    ycrcb = cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb).astype(np.float64)
    return float(np.abs(np.diff(ycrcb[:, :, 1:], axis=1)).mean())


def _block_edges(plane: Floats, period: int) -> float:
    """Mean step across block boundaries of `period` columns over the mean step inside."""
    steps = np.abs(np.diff(plane, axis=1))
    at_edge = (np.arange(steps.shape[1]) % period) == period - 1
    return float(steps[:, at_edge].mean() / steps[:, ~at_edge].mean())


def _textured_frame(camera: CameraEffects, seed: int = 0) -> Scene:
    """A frame of textured background and colourful clutter, no tag (no edge of it falls on
    the JPEG block grid by construction)."""
    base = Effects(backgrounds=("textured",), clutter=(15, 15), noise_sigma=(2.0, 2.0))
    return SceneGenerator(_SMALL, seed=seed, effects=_with(camera, base)).scene_from_poses([])


def _ycrcb(image: Image) -> Floats:
    return cv2.cvtColor(image[:, :, :3], cv2.COLOR_BGR2YCrCb).astype(np.float64)


@settings(max_examples=20, deadline=None)
@given(quality=st.integers(40, 95), seed=st.integers(0, 3))
def test_jpeg_subsamples_chroma_and_leaves_blocks(quality: int, seed: int) -> None:
    stripes = _stripes()
    coded = jpeg(stripes, quality)
    assert coded.shape == stripes.shape and not np.array_equal(coded, stripes)
    # 4:2:0 averages chroma over 2x2 pixels: the column-to-column colour change is gone, where
    # full-resolution chroma (4:4:4) at the same quality keeps most of it
    full = _encode_444(stripes, quality)
    assert _chroma_detail(coded) < 0.1 * _chroma_detail(stripes)
    assert _chroma_detail(full) > 0.5 * _chroma_detail(stripes)
    # on a rendered frame: luma is coded as with 4:4:4, chroma loses clearly more
    frame = _textured_frame(_NEUTRAL, seed).image[:, :, :3]
    original = _ycrcb(frame)
    ours = np.abs(_ycrcb(jpeg(frame, quality)) - original).mean(axis=(0, 1))
    theirs = np.abs(_ycrcb(_encode_444(frame, quality)) - original).mean(axis=(0, 1))
    assert ours[0] == pytest.approx(theirs[0], rel=0.02)
    assert ours[1:].mean() > 1.15 * theirs[1:].mean()


@pytest.mark.parametrize("quality", [40, 50, 65])
def test_generator_compresses_frames_into_visible_blocks(quality: int) -> None:
    before = _ycrcb(_textured_frame(_NEUTRAL).image)
    scene = _textured_frame(CameraEffects(jpeg_quality=(quality, quality)))
    assert scene.effects.camera.jpeg_quality == quality
    after = _ycrcb(scene.image)
    assert 0.5 < float(np.abs(after[:, :, 0] - before[:, :, 0]).mean()) < 10.0
    # steps across block boundaries stand out from those inside the blocks: 8 pixels wide in
    # luma, 16 in chroma (8 subsampled chroma pixels)
    assert _block_edges(before[:, :, 0], 8) < 1.15
    assert _block_edges(after[:, :, 0], 8) > _block_edges(before[:, :, 0], 8) + 0.3
    for channel in (1, 2):
        assert _block_edges(before[:, :, channel], 16) < 1.15
        assert _block_edges(after[:, :, channel], 16) > 1.5


# ------------------------------------------------------------------ exposure and gamma


@settings(max_examples=60, deadline=None)
@given(
    stops=st.floats(-4.0, 4.0),
    crush=st.floats(0.0, 0.6),
    gamma=st.floats(0.25, 4.0),
)
def test_tone_curve_is_monotonic_clips_and_crushes(
    stops: float, crush: float, gamma: float
) -> None:
    curve = tone_curve(stops, crush, gamma).astype(np.int64)
    assert curve.shape == (256,) and np.all(np.diff(curve) >= 0)
    gain = 2.0**stops
    # levels the exposure pushes past white are clipped, those below the crush are black
    white_from = math.ceil(255.0 / gain) + 1
    if white_from <= 255:
        assert np.all(curve[white_from:] == 255)
    black_to = math.floor(crush * 255.0 / gain) - 1
    if black_to >= 0:
        assert np.all(curve[: black_to + 1] == 0)


@pytest.mark.parametrize(
    ("camera", "check"),
    [
        (CameraEffects(exposure_stops=(1.5, 1.5)), "clipped"),
        (CameraEffects(exposure_stops=(-1.5, -1.5)), "darker"),
        (CameraEffects(black_crush=(0.3, 0.3)), "crushed"),
        (CameraEffects(gamma=(2.0, 2.0)), "darker"),
        (CameraEffects(gamma=(0.5, 0.5)), "brighter"),
    ],
)
def test_exposure_and_gamma_on_a_frame(camera: CameraEffects, check: str) -> None:
    base = Effects(backgrounds=("gradient",), marker_black=(40, 40), marker_white=(200, 200))
    before = _f(_facing_scene(_NEUTRAL, base=base).image)
    after = _f(_facing_scene(camera, base=base).image)
    if check == "clipped":
        assert (after == 255).mean() > (before == 255).mean() + 0.3
    elif check == "crushed":
        assert (after == 0).mean() > (before == 0).mean() + 0.1
    elif check == "darker":
        assert after.mean() < 0.8 * before.mean()
    else:
        assert after.mean() > 1.15 * before.mean()


# ------------------------------------------------------------------ shadows, glare, paper


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    depth=st.floats(0.3, 0.9),
    soft=st.sampled_from([0.0, 0.15]),
)
def test_a_shadow_darkens_part_of_the_tag(seed: int, depth: float, soft: float) -> None:
    camera = CameraEffects(
        shadow_probability=1.0, shadow_depth=(depth, depth), shadow_softness=(soft, soft)
    )
    scene = _facing_scene(camera, seed=seed)
    before, after = _f(_facing_scene(_NEUTRAL, seed=seed).image), _f(scene.image)
    (tag,) = scene.markers
    inside = _inside(tag.corners, after.shape)
    ratio = (after[:, :, 1] + 1.0) / (before[:, :, 1] + 1.0)
    assert np.all(ratio <= 1.0 + 1e-9)  # a shadow only takes light away
    on_tag = ratio[inside]
    # it crosses the tag: part of it in shadow, part of it lit. A hard edge gives full shadow
    # and full light; a soft edge spreads both, so only the deeper and the lighter half are
    # sure to be on the tag (its full depth may lie beside it).
    if soft == 0.0:
        assert (np.abs(on_tag - (1.0 - depth)) < 0.06).mean() > 0.02
        assert (on_tag > 0.99).mean() > 0.05
    else:
        assert on_tag.min() < 1.0 - 0.5 * depth < on_tag.max()
    assert after[:, :, 1][inside].mean() < before[:, :, 1][inside].mean()


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), strength=st.floats(0.6, 1.0))
def test_glare_lies_partly_over_the_tag(seed: int, strength: float) -> None:
    camera = CameraEffects(glare_probability=1.0, glare_strength=(strength, strength))
    scene = _facing_scene(camera, seed=seed)
    before, after = _f(_facing_scene(_NEUTRAL, seed=seed).image), _f(scene.image)
    (tag,) = scene.markers
    assert np.all(after >= before)  # glare only adds light
    # at its core a black cell turns almost white
    black = before[:, :, 1] < 40
    core = black & (after[:, :, 1] > 30 + 0.8 * strength * 195)
    assert core.any()
    # it straddles the outline of the tag's black square
    brighter = (after[:, :, 1] - before[:, :, 1]) > 5
    inside = _inside(tag.corners, after.shape)
    assert (brighter & inside).any() and (brighter & ~inside).any()


def test_paper_texture_is_grain_on_the_white() -> None:
    camera = CameraEffects(paper_texture=(10.0, 10.0))
    before, after = _f(_facing_scene(_NEUTRAL).image), _f(_facing_scene(camera).image)
    grain = (after - before)[:, :, 1]
    white, black = before[:, :, 1] == 230, before[:, :, 1] == 30
    (tag,) = _facing_scene(camera).markers
    inside = _inside(tag.corners, after.shape, grow=1.2)
    assert grain[white & inside].std() == pytest.approx(10.0, rel=0.25)
    assert abs(grain[white & inside].mean()) < 1.0
    assert grain[black & inside].std() < 0.3 * grain[white & inside].std()
    assert np.all(grain[~_inside(tag.corners, after.shape, grow=1.45)] == 0)  # on the paper only


# ------------------------------------------------------------------ greyscale / IR


@settings(max_examples=20, deadline=None)
@given(
    contrast=st.floats(0.2, 1.0),
    offset=st.floats(0.0, 100.0),
    jpeg_on=st.booleans(),
)
def test_greyscale_frames_have_equal_channels(
    contrast: float, offset: float, jpeg_on: bool
) -> None:
    camera = CameraEffects(
        greyscale_probability=1.0,
        mono_contrast=(contrast, contrast),
        mono_offset=(offset, offset),
        colour_cast=(1.0, 1.0),
        jpeg_quality=(60, 60) if jpeg_on else (0, 0),
    )
    scene = _facing_scene(camera, base=Effects(backgrounds=("textured",), clutter=(6, 6)))
    assert scene.effects.camera.greyscale
    image = scene.image
    assert np.array_equal(image[:, :, 0], image[:, :, 1])
    assert np.array_equal(image[:, :, 1], image[:, :, 2])
    if not jpeg_on:  # lifted blacks and a squeezed range, exactly
        assert image[:, :, 0].min() >= round(offset)
        assert image[:, :, 0].max() <= round(offset + contrast * 255.0) + 1


# ------------------------------------------------------------------ rolling shutter, blur


def _left_edge(image: Image, row: int, near: float) -> float:
    """Sub-pixel x of the step from the white quiet zone (230) to the black border (30) in
    `row`, within 8 pixels of `near`: the left end of a window plus its white coverage."""
    x_from = math.floor(near) - 8
    window = image[row, x_from : x_from + 17, 1].astype(np.float64)
    return x_from - 0.5 + float(((window - 30.0) / 200.0).sum())


@settings(max_examples=12, deadline=None)
@given(magnitude=st.floats(2.0, 40.0), seed=st.integers(0, 10_000))
def test_rolling_shutter_shifts_rows_progressively(magnitude: float, seed: int) -> None:
    scene = _facing_scene(CameraEffects(rolling_shutter_px=(magnitude, magnitude)), seed=seed)
    neutral = _facing_scene(_NEUTRAL, seed=seed)
    (tag,), (flat,) = scene.markers, neutral.markers
    shift = scene.effects.camera.rolling_shutter_px  # the direction is drawn per scene
    assert abs(shift) == pytest.approx(magnitude)
    height = _SMALL.height
    # truth moves with the image: corners are sheared, the pose is the middle row's
    assert np.allclose(tag.corners, shear_points(flat.corners, shift, height))
    assert np.array_equal(tag.tvec, flat.tvec)
    # the tag's left edge (black border against the white quiet zone) moves by
    # shift * (row - middle) / (height - 1) on each row
    left = float(flat.corners[:, 0].min())
    top, bottom = flat.corners[:, 1].min(), flat.corners[:, 1].max()
    for row in range(math.ceil(top) + 4, math.floor(bottom) - 3):
        expected = shift * (row - (height - 1) / 2.0) / (height - 1)
        moved = _left_edge(scene.image, row, left + expected)
        still = _left_edge(neutral.image, row, left)
        assert moved - still == pytest.approx(expected, abs=0.15)
    # and OpenCV reads the sheared tag where the truth puts it
    detections = OpenCvDetector("DICT_4X4_50").detect(scene.gray())
    assert [d.tag_id for d in detections] == [7]
    assert np.abs(detections[0].corners - tag.corners).max() < 1.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_strong_motion_blur_spreads_edges_along_the_motion(seed: int) -> None:
    base = dataclasses.replace(_STILL, motion_blur_px=(16.0, 16.0))
    scene = _facing_scene(_NEUTRAL, base=base, seed=seed)
    neutral = _facing_scene(_NEUTRAL, seed=seed)
    assert scene.effects.motion_blur_px == 16.0
    angle = math.radians(scene.effects.motion_angle_deg)

    def steepest(image: Image) -> float:
        """Largest slope of the image along the direction of motion."""
        gy, gx = np.gradient(_f(image)[:, :, 1])
        return float(np.abs(gx * math.cos(angle) + gy * math.sin(angle)).max())

    # a step crossed by the motion ramps over the blur length whatever its orientation, so
    # the steepest slope along the motion drops to about step / 16
    assert steepest(scene.image) < 0.25 * steepest(neutral.image)


# ------------------------------------------------------------------ sizes and dictionaries


def _sizes(height: int) -> dict[str, tuple[tuple[float, float], float]]:
    """Tag size ranges, as (side_px, partial_fraction): tiny, medium, half the frame, and cut
    by the image border."""
    return {
        "tiny": ((9.0, 13.0), 0.0),
        "medium": ((30.0, 120.0), 0.0),
        "half": ((0.4 * height, 0.5 * height), 0.0),
        "border": ((40.0, 0.3 * height), 1.0),
    }


_SIZE_NAMES = ("tiny", "medium", "half", "border")


def _random_scene(gen: SceneGenerator, size: str) -> Scene:
    side_px, partial = _sizes(gen.camera.height)[size]
    if size == "half":  # one tag that big is all a frame holds
        return gen.random_scene(1, 0, side_px=side_px)
    return gen.random_scene(
        4, 2, distractor_kinds=("decoy",), side_px=side_px, partial_fraction=partial
    )


@pytest.mark.parametrize("size", _SIZE_NAMES)
@pytest.mark.parametrize("resolution", ["VGA", "HD720"])
def test_side_px_asks_for_tag_sizes_in_pixels(size: str, resolution: str) -> None:
    cam = CameraModel.named(resolution)
    gen = SceneGenerator(cam, seed=2, dictionary="DICT_6X6_250")
    (low, high), _ = _sizes(cam.height)[size]
    for _ in range(2):
        scene = _random_scene(gen, size)
        assert len(scene.markers) == (1 if size == "half" else 4)
        for m in scene.markers:
            assert 0.97 * low <= m.side_px <= 1.03 * high
            if size == "border":  # cut by the border, centre inside
                assert not m.visible and cam.contains(m.corner_mean)
            else:
                assert m.visible


@pytest.mark.parametrize("dictionary", _DICTIONARIES)
def test_every_dictionary_family_renders_decodable_tags(dictionary: str) -> None:
    gen = SceneGenerator(_SMALL, seed=3, dictionary=dictionary)
    scene = gen.scene_from_poses([MarkerPose(5, 0.5 * 240 / 300.0, (0.0, 0.0, 1.0))])
    found = OpenCvDetector(dictionary).detect(scene.gray())
    assert [d.tag_id for d in found] == [5]
    assert np.abs(found[0].corners - scene.markers[0].corners).max() < 0.6


# ------------------------------------------------------------------ default detector vs OpenCV

_BASE = Effects.realistic()
_CASES: dict[str, Effects] = {
    "colour_cast": _with(CameraEffects(colour_cast=(0.7, 1.0)), _BASE),
    "jpeg": _with(CameraEffects(jpeg_quality=(40, 60)), _BASE),
    "exposure_gamma": _with(
        CameraEffects(exposure_stops=(-2.0, 1.5), black_crush=(0.05, 0.25), gamma=(0.5, 2.0)),
        _BASE,
    ),
    "shadow": _with(
        CameraEffects(shadow_probability=1.0, shadow_depth=(0.5, 0.85), shadow_softness=(0.0, 0.3)),
        _BASE,
    ),
    "paper_glare": _with(
        CameraEffects(paper_texture=(6.0, 15.0), glare_probability=1.0, glare_strength=(0.4, 1.0)),
        _BASE,
    ),
    "greyscale": _with(
        CameraEffects(greyscale_probability=1.0, mono_contrast=(0.3, 0.7), mono_offset=(30, 90)),
        _BASE,
    ),
    "rolling_shutter": _with(CameraEffects(rolling_shutter_px=(15.0, 40.0)), _BASE),
    "strong_blur": dataclasses.replace(_BASE, motion_blur_px=(10.0, 16.0), blur_sigma=(1.0, 2.5)),
    "real_camera": Effects.real_camera(),
}


def _true_ids(detections: Sequence[Detection], scene: Scene) -> Counter[int]:
    """Ids of the detections that lie on a tag of that id (mean corner error within
    max(4 px, a tenth of its side)), each tag matched once."""
    free = list(scene.markers)
    out: Counter[int] = Counter()
    for d in detections:
        for m in free:
            error = float(np.linalg.norm(d.corners - m.corners, axis=1).mean())
            if m.tag_id == d.tag_id and error <= max(4.0, 0.1 * m.side_px):
                out[d.tag_id] += 1
                free.remove(m)
                break
    return out


@pytest.mark.parametrize("effect", list(_CASES))
def test_default_detector_finds_what_opencv_finds(effect: str) -> None:
    # every effect with every dictionary family, the size range turning with the dictionary so
    # that each effect meets every size; a fresh detector per frame (independent frames)
    index = list(_CASES).index(effect)
    cam = CameraModel.named("HD720" if effect == "real_camera" else "VGA")
    reference_total = 0
    sizes_seen: set[str] = set()
    for j, dictionary in enumerate(_DICTIONARIES):
        size = _SIZE_NAMES[(index + j) % len(_SIZE_NAMES)]
        gen = SceneGenerator(
            cam, seed=100 * index + j, dictionary=dictionary, effects=_CASES[effect]
        )
        scene = _random_scene(gen, size)
        assert scene.markers
        sizes_seen.add(size)
        gray = np.asarray(cv2.cvtColor(scene.image, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)
        reference = _true_ids(OpenCvDetector(dictionary).detect(gray), scene)
        found = _true_ids(make_detector("tracking", dictionary).detect(gray), scene)
        assert reference <= found, (dictionary, size, reference, found)
        reference_total += reference.total()
    assert sizes_seen == set(_SIZE_NAMES)
    assert reference_total > 0  # the comparison is not empty


@pytest.mark.parametrize("dictionary", _DICTIONARIES)
def test_default_detector_reports_no_id_without_tags(dictionary: str) -> None:
    # a short run of frames with clutter and tag-like decoys but no tag, under real camera
    # effects, through one detector as a stream would feed it
    gen = SceneGenerator(
        CameraModel.named("VGA"), seed=7, dictionary=dictionary, effects=Effects.real_camera()
    )
    detector = make_detector("tracking", dictionary)
    for _ in range(4):
        scene = gen.random_scene(0, 3, distractor_kinds=("decoy",), distance_m=(0.5, 4.0))
        assert not scene.markers and scene.distractors
        assert detector.detect(scene.gray()) == []


@pytest.mark.parametrize("dictionary", ["DICT_4X4_50", "DICT_APRILTAG_16h5"])
def test_default_detector_reports_no_id_on_a_drive_past_decoys(dictionary: str) -> None:
    # video: the detector follows its stream (skips still frames, scans periodically)
    gen = SceneGenerator(
        CameraModel.named("VGA"), seed=1, dictionary=dictionary, effects=Effects.real_camera()
    )
    detector = make_detector("tracking", dictionary)
    frames = list(gen.drive(8, n_tags=0, n_distractors=4, distractor_kinds=("decoy",)))
    assert all(not f.markers for f in frames)
    assert sum(len(f.distractors) for f in frames) > 0
    assert all(detector.detect(f.gray()) == [] for f in frames)
