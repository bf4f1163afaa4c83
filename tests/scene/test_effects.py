"""Scene effects: backgrounds, noise, lighting, contrast, blur and motion blur."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt
import pytest

from tests.scene.cases import NEUTRAL, STILL, Image, as_float, facing_scene
from zenoh_perception_bench.scene import (
    CameraModel,
    Effects,
    SceneGenerator,
)


def _flat_scene(effects: Effects, seed: int = 0) -> npt.NDArray[np.float64]:
    gen = SceneGenerator(CameraModel(320, 240, 300, 300, 159.5, 119.5), seed=seed, effects=effects)
    return gen.scene_from_poses([]).image[:, :, :3].astype(np.float64)


def test_plain_background_is_flat_and_effects_act_as_specified() -> None:
    plain = _flat_scene(Effects())
    assert plain.std(axis=(0, 1)).max() == 0.0
    noisy = _flat_scene(Effects(noise_sigma=(6.0, 6.0)))
    assert noisy.std(axis=(0, 1)) == pytest.approx([6.0] * 3, rel=0.1)
    lit = _flat_scene(Effects(lighting_gradient=(0.5, 0.5)))
    ratio = lit[:, :, 1].min() / lit[:, :, 1].max()
    assert ratio == pytest.approx(0.5, abs=0.02)
    contrast = _flat_scene(Effects(contrast=(0.5, 0.5), brightness=(10.0, 10.0)))
    assert np.allclose(contrast, np.rint(plain * 0.5 + 64.0 + 10.0), atol=1.0)


def test_textured_background_and_blur() -> None:
    textured = _flat_scene(Effects(backgrounds=("textured",), clutter=(5, 5)))
    assert textured.std() > 10.0
    for blurred in (
        _flat_scene(Effects(backgrounds=("textured",), clutter=(5, 5), blur_sigma=(2.0, 2.0))),
        _flat_scene(Effects(backgrounds=("textured",), clutter=(5, 5), motion_blur_px=(6.0, 6.0))),
    ):
        # same seed, same background: blurring only lowers the high-frequency energy
        grad = np.abs(np.diff(textured, axis=1)).mean()
        assert np.abs(np.diff(blurred, axis=1)).mean() < 0.8 * grad


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_strong_motion_blur_spreads_edges_along_the_motion(seed: int) -> None:
    base = dataclasses.replace(STILL, motion_blur_px=(16.0, 16.0))
    scene = facing_scene(NEUTRAL, base=base, seed=seed)
    neutral = facing_scene(NEUTRAL, seed=seed)
    assert scene.effects.motion_blur_px == 16.0
    angle = math.radians(scene.effects.motion_angle_deg)

    def steepest(image: Image) -> float:
        """Largest slope of the image along the direction of motion."""
        gy, gx = np.gradient(as_float(image)[:, :, 1])
        return float(np.abs(gx * math.cos(angle) + gy * math.sin(angle)).max())

    # a step crossed by the motion ramps over the blur length whatever its orientation, so
    # the steepest slope along the motion drops to about step / 16
    assert steepest(scene.image) < 0.25 * steepest(neutral.image)
