"""The colour check: black-on-white tags pass, coloured look-alikes that decode do not."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.detect.colour import (
    DEFAULT_MAX_CHROMA,
    NO_COLOUR_CHECK,
    ChromaCheck,
    ColourLimits,
    ColourMeasure,
)
from zenoh_perception.detect.refine import MarkerModel
from zenoh_perception.detection import Detection, aruco_dictionary
from zenoh_perception.fast_detector import FastDetector
from zenoh_perception.frames import ENCODINGS, Frame
from zenoh_perception.pipeline import Pipeline
from zenoh_perception.scene import CameraModel, Effects, SceneGenerator
from zenoh_perception.settings import Settings

DICT = aruco_dictionary("DICT_4X4_50")
LIMITS = ColourLimits()  # the defaults
CELL = 12  # pixels per cell of the drawn tags
SIDE = 6 * CELL


def _tag_on_canvas(
    tag_id: int,
    white: tuple[int, int, int],
    black: tuple[int, int, int],
    background: tuple[int, int, int] = (128, 128, 128),
    quiet_zone: bool = True,
) -> tuple[npt.NDArray[np.uint8], Detection]:
    """A 200x200 BGRA canvas with tag ``tag_id`` drawn in the given colours at (64, 64)."""
    cells = cv2.aruco.generateImageMarker(DICT, tag_id, 6, borderBits=1) > 127
    big = np.kron(cells, np.ones((CELL, CELL), dtype=bool))
    canvas = np.empty((200, 200, 4), dtype=np.uint8)
    canvas[:, :, :3] = background
    canvas[:, :, 3] = 255
    if quiet_zone:
        canvas[64 - CELL : 64 + SIDE + CELL, 64 - CELL : 64 + SIDE + CELL, :3] = white
    patch = np.where(big[:, :, None], np.array(white), np.array(black)).astype(np.uint8)
    canvas[64 : 64 + SIDE, 64 : 64 + SIDE, :3] = patch
    corners = np.array(
        [[63.5, 63.5], [63.5 + SIDE, 63.5], [63.5 + SIDE, 63.5 + SIDE], [63.5, 63.5 + SIDE]],
        dtype=np.float32,
    )
    return canvas, Detection(tag_id, corners)


def test_a_black_on_white_tag_has_no_chroma() -> None:
    image, det = _tag_on_canvas(7, (250, 250, 250), (15, 15, 15))
    (measure,) = ChromaCheck(DICT).measure(image, [det])
    assert measure.chroma < 0.01
    assert measure.black_tint < 0.01
    assert measure.achromatic(LIMITS)


def test_a_yellow_pictogram_on_a_dark_box_is_colourful() -> None:
    image, det = _tag_on_canvas(7, (20, 220, 250), (25, 30, 20), quiet_zone=False)
    (measure,) = ChromaCheck(DICT).measure(image, [det])
    assert measure.chroma > 0.5
    assert not measure.achromatic(LIMITS)


@given(
    gain=st.floats(0.3, 0.9),
    offset=st.integers(0, 40),
    ink=st.floats(0.0, 0.15),
    tint=st.tuples(*[st.floats(0.9, 1.0)] * 3),
)
def test_tags_under_any_near_white_light_pass(
    gain: float, offset: int, ink: float, tint: tuple[float, float, float]
) -> None:
    """Brightness, a grey black level, a light tint (white balance within 10 %) and ink that
    reflects a little of the light, in its colour, keep a tag in."""
    light = [gain * 230 * t for t in tint]
    white = tuple(round(offset + v) for v in light)
    black = tuple(round(offset + ink * v) for v in light)
    image, det = _tag_on_canvas(3, white, black)  # type: ignore[arg-type]
    (measure,) = ChromaCheck(DICT).measure(image, [det])
    spread = (max(tint) - min(tint)) / (sum(tint) / 3.0)  # the light's own chroma
    # drawn in integers: each channel's white-minus-black is off by up to 1 level
    levels = (sum(white) - sum(black)) / 3.0
    assert measure.chroma <= spread + 2.0 / levels + 0.01
    assert measure.black_tint < 1.0  # (rounding to integers)
    assert measure.achromatic(LIMITS)


def _noisy(image: npt.NDArray[np.uint8], sigma: float, seed: int) -> npt.NDArray[np.uint8]:
    noise = np.random.default_rng(seed).normal(0.0, sigma, image.shape)
    return np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("dark", [(40, 30, 18), (48, 26, 30), (22, 34, 26)])
def test_a_white_pictogram_on_a_tinted_dark_box_is_caught(dark: tuple[int, int, int]) -> None:
    """The contrast of a white code on a dark brown, purple or green box is near grey (the
    first measure passes it); its dark is not the colour of the light."""
    image, det = _tag_on_canvas(7, (235, 235, 235), dark, background=(235, 235, 235))
    (measure,) = ChromaCheck(DICT).measure(_noisy(image, 3.0, seed=1), [det])
    assert measure.chroma < DEFAULT_MAX_CHROMA
    assert measure.black_tint > 5.0
    assert measure.black_tint_z > 10.0
    assert not measure.achromatic(LIMITS)


def test_noise_alone_does_not_tint_the_black() -> None:
    """Heavy sensor noise on a grey black: the tint is within its standard error."""
    image, det = _tag_on_canvas(7, (200, 200, 200), (30, 30, 30))
    check = ChromaCheck(DICT)
    measures = [check.measure(_noisy(image, 12.0, seed), [det])[0] for seed in range(40)]
    assert max(m.black_tint for m in measures) > 2.0  # the noise does move the mean...
    assert all(m.achromatic(LIMITS) for m in measures)  # ...within its error


@given(channel=st.integers(0, 2), strength=st.floats(0.5, 1.0))
def test_a_code_printed_in_one_colour_is_caught(channel: int, strength: float) -> None:
    white = [40, 40, 40]
    white[channel] = 40 + round(200 * strength)
    image, det = _tag_on_canvas(11, tuple(white), (20, 20, 20))  # type: ignore[arg-type]
    (measure,) = ChromaCheck(DICT).measure(image, [det])
    assert measure.chroma > DEFAULT_MAX_CHROMA


def test_keep_filters_and_needs_colour() -> None:
    image, real = _tag_on_canvas(5, (240, 240, 240), (10, 10, 10))
    coloured, fake = _tag_on_canvas(9, (30, 200, 250), (20, 20, 20), quiet_zone=False)
    wide = np.concatenate([image, coloured], axis=1)  # the coloured one 200 px to the right
    fake = Detection(9, fake.corners + np.array([200.0, 0.0], dtype=np.float32))
    check = ChromaCheck(DICT)
    assert [d.tag_id for d in check.keep(wide, [real, fake], LIMITS)] == [5]
    assert [d.tag_id for d in check.keep(wide, [real, fake], ColourLimits(10.0))] == [5, 9]
    assert check.keep(wide, [], LIMITS) == []
    with pytest.raises(ValueError, match="colour image"):
        check.measure(np.zeros((20, 20), dtype=np.uint8), [real])


def _frame(image: npt.NDArray[np.uint8]) -> Frame:
    return Frame(image, ENCODINGS["bgra8"], None, "test", None)


@pytest.mark.parametrize("detector", ["fast", "opencv"])
def test_pipeline_drops_a_coloured_code_unless_the_check_is_off(detector: str) -> None:
    image, _ = _tag_on_canvas(9, (20, 220, 250), (25, 30, 20), background=(235, 235, 235))
    on = Pipeline(Settings(detector=detector)).process(_frame(image))
    unchecked = Settings(detector=detector, max_tag_chroma=0.0, max_black_tint=0.0)
    off = Pipeline(unchecked).process(_frame(image))
    assert [t.tag_id for t in off.tags] == [9]  # it decodes: a look-alike in grey
    assert on.tags == ()
    assert on.selected.tag_id == -1


@pytest.mark.parametrize("detector", ["fast", "opencv"])
def test_pipeline_drops_a_white_code_on_a_tinted_box_unless_the_tint_check_is_off(
    detector: str,
) -> None:
    image, _ = _tag_on_canvas(6, (235, 235, 235), (40, 30, 18), background=(235, 235, 235))
    image = _noisy(image, 2.0, seed=3)
    on = Pipeline(Settings(detector=detector)).process(_frame(image))
    off = Pipeline(Settings(detector=detector, max_black_tint=0.0)).process(_frame(image))
    assert [t.tag_id for t in off.tags] == [6]  # the contrast check alone passes it
    assert on.tags == ()


def test_generated_tags_pass_the_check() -> None:
    """Real tags of generated scenes (lighting, noise, blur) measure far below the limit."""
    generator = SceneGenerator(CameraModel.named("VGA"), seed=5, effects=Effects.realistic())
    check = ChromaCheck(DICT)
    measures: list[ColourMeasure] = []
    for _ in range(6):
        scene = generator.random_scene(4, 0, size_m=(0.15, 0.3), distance_m=(0.8, 3.0))
        truth = [
            Detection(m.tag_id, m.corners.astype(np.float32))
            for m in scene.markers
            if m.visible and not m.occluded
        ]
        measures += check.measure(scene.image, truth)
    assert len(measures) >= 12
    assert max(m.chroma for m in measures) < DEFAULT_MAX_CHROMA / 2
    assert all(m.achromatic(LIMITS) for m in measures)


def test_the_fast_detector_checks_colour_before_refining() -> None:
    """A code printed yellow on dark green, quiet zone included, is a marker in grey: the
    detector's own check drops it before the model fit ever sees it."""
    image, _ = _tag_on_canvas(9, (20, 220, 250), (25, 60, 20), background=(120, 120, 120))
    unchecked = FastDetector().detect_converting(image, cv2.COLOR_BGRA2GRAY, NO_COLOUR_CHECK)
    assert [d.tag_id for d in unchecked] == [9]
    detector = FastDetector()
    assert detector.detect_converting(image, cv2.COLOR_BGRA2GRAY, LIMITS) == []
    assert detector.stats.colour_rejected >= 1
    assert detector.stats.rejected == 0  # never refined and fitted
    grey, real = _tag_on_canvas(9, (235, 235, 235), (20, 20, 20))
    kept = FastDetector().detect_converting(grey, cv2.COLOR_BGRA2GRAY, LIMITS)
    assert [d.tag_id for d in kept] == [real.tag_id]


def test_checking_candidates_finds_what_checking_detections_finds() -> None:
    """On independent frames full of look-alikes (coloured and white), the detector checking
    its candidates reports exactly what checking its detections afterwards reported."""
    generator = SceneGenerator(CameraModel.named("VGA"), seed=11, effects=Effects.realistic())
    check = ChromaCheck(DICT)
    rejected = reported = 0
    for _ in range(12):
        scene = generator.random_scene(2, 6)
        detector = FastDetector()
        early = detector.detect_converting(scene.image, cv2.COLOR_BGRA2GRAY, LIMITS)
        rejected += detector.stats.colour_rejected
        late = check.keep(
            scene.image,
            FastDetector().detect_converting(scene.image, cv2.COLOR_BGRA2GRAY, NO_COLOUR_CHECK),
            LIMITS,
        )
        assert [d.tag_id for d in early] == [d.tag_id for d in late]
        for a, b in zip(early, late, strict=True):
            # (refined in other batches: a batch iterates until its slowest candidate settles)
            np.testing.assert_allclose(a.corners, b.corners, atol=0.05)
        reported += len(early)
    assert rejected > 0  # the frames did hold coloured look-alikes
    assert reported > 0


@pytest.mark.parametrize("detector", ["fast", "opencv"])
def test_pipeline_drops_tags_smaller_than_the_minimum_side(detector: str) -> None:
    image, _ = _tag_on_canvas(4, (240, 240, 240), (15, 15, 15))  # a 72 px tag
    for min_side, expected in ((0.0, [4]), (70.0, [4]), (75.0, [])):
        settings = Settings(detector=detector, min_tag_side_px=min_side)
        analysis = Pipeline(settings).process(_frame(image))
        assert [t.tag_id for t in analysis.tags] == expected, min_side


def _reference_measure(
    values: npt.NDArray[np.float64], black: npt.NDArray[np.bool_]
) -> tuple[float, float, float]:
    """The module doc's measures, spelled out on arrays: (chroma, black tint, tint / error)."""
    white_mean, black_mean = values[~black].mean(axis=0), values[black].mean(axis=0)
    difference = white_mean - black_mean
    chroma = float(np.ptp(difference) / max(difference.mean(), 1.0))
    allowed = (white_mean - white_mean.mean()) * black_mean.mean() / max(white_mean.mean(), 1.0)
    black_chroma = black_mean - black_mean.mean()
    share = 0.0
    if allowed @ allowed > 0.0:
        share = float(np.clip(black_chroma @ allowed / (allowed @ allowed), 0.0, 1.0))
    excess = np.abs(black_chroma - share * allowed)
    channel = int(np.argmax(excess))
    cells = values[black] - values[black].mean(axis=1, keepdims=True)
    error = max(float(cells[:, channel].std(ddof=1)) / np.sqrt(len(cells)), 0.1)
    return chroma, float(excess[channel]), float(excess[channel]) / error


@given(seed=st.integers(0, 2**32 - 1), tint=st.floats(-20.0, 20.0), noise=st.floats(0.0, 15.0))
def test_the_measures_match_a_reference_implementation(
    seed: int, tint: float, noise: float
) -> None:
    """On a drawn tag's cell samples, the sums of squares the check uses give what the plain
    formulas give."""
    rng = np.random.default_rng(seed)
    tag_id = int(rng.integers(50))
    white = tuple(int(v) for v in rng.integers(120, 250, 3))
    dark = tuple(int(np.clip(30 + tint * rng.uniform(-1, 1), 0, 255)) for _ in range(3))
    image, det = _tag_on_canvas(tag_id, white, dark)  # type: ignore[arg-type]
    image = _noisy(image, noise, seed)
    (measure,) = ChromaCheck(DICT).measure(image, [det])
    # the same cell-centre samples as the check's
    corners = np.asarray(det.corners, dtype=np.float64)
    samples = MarkerModel(DICT).cell_samples(image, [corners])[0, :, :3]
    cells = cv2.aruco.generateImageMarker(DICT, tag_id, 6, borderBits=1) < 128
    expected = _reference_measure(samples, cells.ravel())
    got = (measure.chroma, measure.black_tint, measure.black_tint_z)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-9)
