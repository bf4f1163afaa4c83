"""What real cameras add to synthetic scenes (`CameraEffects`, `Effects.real_camera`): coloured
light, JPEG, exposure and gamma, shadows, glare, paper grain, greyscale sensors, rolling shutter."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.scene.cases import (
    NEUTRAL,
    SMALL,
    Floats,
    Image,
    as_float,
    facing_scene,
    inside_quad,
    with_camera,
)
from zenoh_perception.detect.opencv import OpenCvDetector
from zenoh_perception_bench.scene import (
    CAST_KINDS,
    CameraEffects,
    CameraModel,
    CameraParams,
    Effects,
    Scene,
    SceneError,
    SceneGenerator,
)
from zenoh_perception_bench.scene._camera_effects import (
    colour_cast,
    jpeg,
    shear_points,
    tone_curve,
)


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
    gen = SceneGenerator(SMALL)
    with pytest.raises(SceneError):
        gen.random_scene(1, side_px=(20.0, 10.0))


def test_one_seed_gives_one_layout_whatever_the_camera_effects() -> None:
    cam = CameraModel.named("VGA")

    def scene(camera: CameraEffects) -> Scene:
        gen = SceneGenerator(cam, seed=4, effects=with_camera(camera, Effects.realistic()))
        return gen.random_scene(3, 2)

    neutral, real = scene(NEUTRAL), scene(CameraEffects.real_camera())
    assert neutral.ids == real.ids
    for a, b in zip(neutral.markers, real.markers, strict=True):
        assert np.array_equal(a.tvec, b.tvec) and np.array_equal(a.rvec, b.rvec)
    assert not np.array_equal(neutral.image, real.image)
    # strengths of zero change no pixel, whichever option carries them
    glare_off = scene(CameraEffects(glare_probability=1.0))
    assert np.array_equal(neutral.image, glare_off.image)


@settings(max_examples=20, deadline=None)
@given(gains=st.tuples(*[st.floats(0.4, 1.6)] * 3))
def test_colour_gains_move_each_channel_their_way(gains: tuple[float, float, float]) -> None:
    neutral = facing_scene(NEUTRAL).image[:, :, :3]
    cast = colour_cast(neutral, gains)
    before, after = as_float(neutral).mean(axis=(0, 1)), cast.astype(np.float64).mean(axis=(0, 1))
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
    scene = facing_scene(camera)
    assert scene.effects.camera.cast == kind
    neutral = as_float(facing_scene(NEUTRAL).image).mean(axis=(0, 1))
    tinted = as_float(scene.image).mean(axis=(0, 1))
    # the light's dominant channel gains on its weakest one by a clear margin
    assert tinted[strong] / tinted[weak] > 1.4 * neutral[strong] / neutral[weak]


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
    return SceneGenerator(SMALL, seed=seed, effects=with_camera(camera, base)).scene_from_poses([])


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
    frame = _textured_frame(NEUTRAL, seed).image[:, :, :3]
    original = _ycrcb(frame)
    ours = np.abs(_ycrcb(jpeg(frame, quality)) - original).mean(axis=(0, 1))
    theirs = np.abs(_ycrcb(_encode_444(frame, quality)) - original).mean(axis=(0, 1))
    assert ours[0] == pytest.approx(theirs[0], rel=0.02)
    assert ours[1:].mean() > 1.15 * theirs[1:].mean()


@pytest.mark.parametrize("quality", [40, 50, 65])
def test_generator_compresses_frames_into_visible_blocks(quality: int) -> None:
    before = _ycrcb(_textured_frame(NEUTRAL).image)
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
    before = as_float(facing_scene(NEUTRAL, base=base).image)
    after = as_float(facing_scene(camera, base=base).image)
    if check == "clipped":
        assert (after == 255).mean() > (before == 255).mean() + 0.3
    elif check == "crushed":
        assert (after == 0).mean() > (before == 0).mean() + 0.1
    elif check == "darker":
        assert after.mean() < 0.8 * before.mean()
    else:
        assert after.mean() > 1.15 * before.mean()


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
    scene = facing_scene(camera, seed=seed)
    before, after = as_float(facing_scene(NEUTRAL, seed=seed).image), as_float(scene.image)
    (tag,) = scene.markers
    inside = inside_quad(tag.corners, after.shape)
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
@given(seed=st.integers(0, 10_000), depth=st.floats(0.4, 0.9), period=st.floats(0.3, 1.0))
def test_stripes_cross_the_tag_and_its_surround_with_hard_edges(
    seed: int, depth: float, period: float
) -> None:
    camera = CameraEffects(
        stripes_probability=1.0, stripes_depth=(depth, depth), stripes_period=(period, period)
    )
    scene = facing_scene(camera, seed=seed)
    before, after = as_float(facing_scene(NEUTRAL, seed=seed).image), as_float(scene.image)
    (tag,) = scene.markers
    ratio = (after[:, :, 1] + 1.0) / (before[:, :, 1] + 1.0)
    assert np.all(ratio <= 1.0 + 1e-9)  # stripes only take light away
    inside = inside_quad(tag.corners, after.shape)
    around = inside_quad(tag.corners, after.shape, grow=1.8) & ~inside
    white = before[:, :, 1] > 150  # the ratio of a dark pixel is mostly rounding
    # on the tag and on the paper around it: stripes fully dark or fully lit, few between
    # (a stripe may be wider than the tag, so the two levels are asked of both together)
    for region in (inside & white, around & white):
        shaded = np.abs(ratio[region] - (1.0 - depth)) < 0.06
        lit = ratio[region] > 0.99
        assert (shaded | lit).mean() > 0.75
    both = (inside | around) & white
    assert (np.abs(ratio[both] - (1.0 - depth)) < 0.06).mean() > 0.05
    assert (ratio[both] > 0.99).mean() > 0.05


def test_no_stripes_unless_asked() -> None:
    neutral = facing_scene(NEUTRAL, seed=3).image
    assert np.array_equal(
        facing_scene(CameraEffects(stripes_depth=(0.8, 0.8)), seed=3).image, neutral
    )


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), strength=st.floats(0.6, 1.0))
def test_glare_lies_partly_over_the_tag(seed: int, strength: float) -> None:
    camera = CameraEffects(glare_probability=1.0, glare_strength=(strength, strength))
    scene = facing_scene(camera, seed=seed)
    before, after = as_float(facing_scene(NEUTRAL, seed=seed).image), as_float(scene.image)
    (tag,) = scene.markers
    assert np.all(after >= before)  # glare only adds light
    # at its core a black cell turns almost white
    black = before[:, :, 1] < 40
    core = black & (after[:, :, 1] > 30 + 0.8 * strength * 195)
    assert core.any()
    # it straddles the outline of the tag's black square
    brighter = (after[:, :, 1] - before[:, :, 1]) > 5
    inside = inside_quad(tag.corners, after.shape)
    assert (brighter & inside).any() and (brighter & ~inside).any()


def test_paper_texture_is_grain_on_the_white() -> None:
    camera = CameraEffects(paper_texture=(10.0, 10.0))
    before, after = as_float(facing_scene(NEUTRAL).image), as_float(facing_scene(camera).image)
    grain = (after - before)[:, :, 1]
    white, black = before[:, :, 1] == 230, before[:, :, 1] == 30
    (tag,) = facing_scene(camera).markers
    inside = inside_quad(tag.corners, after.shape, grow=1.2)
    assert grain[white & inside].std() == pytest.approx(10.0, rel=0.25)
    assert abs(grain[white & inside].mean()) < 1.0
    assert grain[black & inside].std() < 0.3 * grain[white & inside].std()
    assert np.all(
        grain[~inside_quad(tag.corners, after.shape, grow=1.45)] == 0
    )  # on the paper only


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
    scene = facing_scene(camera, base=Effects(backgrounds=("textured",), clutter=(6, 6)))
    assert scene.effects.camera.greyscale
    image = scene.image
    assert np.array_equal(image[:, :, 0], image[:, :, 1])
    assert np.array_equal(image[:, :, 1], image[:, :, 2])
    if not jpeg_on:  # lifted blacks and a squeezed range, exactly
        assert image[:, :, 0].min() >= round(offset)
        assert image[:, :, 0].max() <= round(offset + contrast * 255.0) + 1


def _left_edge(image: Image, row: int, near: float) -> float:
    """Sub-pixel x of the step from the white quiet zone (230) to the black border (30) in
    `row`, within 8 pixels of `near`: the left end of a window plus its white coverage."""
    x_from = math.floor(near) - 8
    window = image[row, x_from : x_from + 17, 1].astype(np.float64)
    return x_from - 0.5 + float(((window - 30.0) / 200.0).sum())


@settings(max_examples=12, deadline=None)
@given(magnitude=st.floats(2.0, 40.0), seed=st.integers(0, 10_000))
def test_rolling_shutter_shifts_rows_progressively(magnitude: float, seed: int) -> None:
    scene = facing_scene(CameraEffects(rolling_shutter_px=(magnitude, magnitude)), seed=seed)
    neutral = facing_scene(NEUTRAL, seed=seed)
    (tag,), (flat,) = scene.markers, neutral.markers
    shift = scene.effects.camera.rolling_shutter_px  # the direction is drawn per scene
    assert abs(shift) == pytest.approx(magnitude)
    height = SMALL.height
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
