"""The static world a drive passes through: tags and look-alikes on posts, ground and sky."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._distractors import plate_ratio
from zenoh_perception_bench.scene._effects import (
    EffectParams,
    Effects,
    colourise,
    draw_clutter,
    draw_rocks,
    lowpass_noise,
)
from zenoh_perception_bench.scene._geometry import R_FACING, CameraModel, rot_x, rot_y, rot_z


@dataclass(frozen=True)
class WorldObject:
    position: npt.NDArray[np.float64]
    rotation: npt.NDArray[np.float64]
    size_m: float
    tag_id: int = -1
    kind: str = ""
    mimic_id: int | None = None
    ratio: float = 1.0
    seed: int = 0
    post_colour: tuple[float, float, float] = (60.0, 60.0, 60.0)


@dataclass(frozen=True)
class World:
    """Static world of a drive: tags, distractors, ground texture, sky, effect values."""

    objects: tuple[WorldObject, ...]
    texture: npt.NDArray[np.uint8]
    texel_m: float
    x_min: float
    z_max: float
    ground_y: float
    far_colour: tuple[float, float, float]
    sky: npt.NDArray[np.uint8]
    params: EffectParams

    @classmethod
    def build(
        cls,
        rng: np.random.Generator,
        camera: CameraModel,
        effects: Effects,
        *,
        ids: list[int],
        n_distractors: int,
        kinds: tuple[str, ...],
        size_m: tuple[float, float],
        travel_m: float,
        camera_height_m: float,
        n_ids: int,
    ) -> World:
        params = effects.sample(rng)
        n_objects = len(ids) + n_distractors
        far = travel_m + 7.0
        slots = rng.permutation(max(n_objects, 1))
        objects: list[WorldObject] = []
        for n in range(n_objects):
            z = 3.0 + (far - 3.0) * (float(slots[n]) + float(rng.uniform(0.15, 0.85))) / n_objects
            side = 1.0 if rng.random() < 0.5 else -1.0
            x = side * float(rng.uniform(0.3, 1.6))
            size = float(rng.uniform(size_m[0], size_m[1]))
            lift = float(rng.uniform(size * 0.6 + 0.05, max(size * 0.6 + 0.1, 1.0)))
            y = camera_height_m - lift
            rotation = (
                rot_y(float(rng.uniform(-35, 35)) - side * 10.0)
                @ rot_x(float(rng.uniform(-12, 12)))
                @ rot_z(float(rng.uniform(-12, 12)))
                @ R_FACING
            )
            seed = int(rng.integers(2**31))
            grey = float(rng.uniform(30, 120))
            post = (grey, grey + float(rng.uniform(-10, 10)), grey + float(rng.uniform(-10, 10)))
            position = np.array([x, y, z])
            if n < len(ids):
                objects.append(
                    WorldObject(
                        position, rotation, size, tag_id=ids[n], seed=seed, post_colour=post
                    )
                )
            else:
                kind = kinds[int(rng.integers(len(kinds)))]
                mimic = None if kind == "decoy" else int(rng.integers(n_ids))
                ratio = plate_ratio(kind, rng)
                objects.append(
                    WorldObject(
                        position,
                        rotation,
                        size,
                        kind=kind,
                        mimic_id=mimic,
                        ratio=ratio,
                        seed=seed,
                        post_colour=post,
                    )
                )
        texel = max(0.03, (far + 30.0) / 4096.0)
        width_m = 24.0
        tex_w = round(width_m / texel)
        tex_h = round((far + 32.0) / texel)
        index = lowpass_noise(tex_w, tex_h, rng, float(rng.uniform(0.4, 2.0)) / texel, octaves=4)
        low = np.clip(rng.uniform(40, 100) + rng.uniform(-15, 15, 3), 0, 255)
        high = np.clip(rng.uniform(120, 200) + rng.uniform(-15, 15, 3), 0, 255)
        texture = colourise(index, low, high)
        area_m2 = width_m * (far + 32.0)
        draw_rocks(texture, round(area_m2 * 0.6), rng, (0.03 / texel, 0.35 / texel))
        draw_clutter(texture, params.clutter, rng, size=(0.3 * texel, 1.5 * texel))
        texture = np.asarray(cv2.GaussianBlur(texture, (0, 0), 0.6), dtype=np.uint8)
        mean = texture.reshape(-1, 3).mean(axis=0)
        top = np.clip(rng.uniform(170, 230) + np.array([25.0, 5.0, -15.0]), 0, 255)
        bottom = np.clip(rng.uniform(190, 245) + rng.uniform(-10, 10, 3), 0, 255)
        column = np.linspace(0.0, 1.0, camera.height)[:, None] * (bottom - top) + top
        sky = np.ascontiguousarray(
            np.broadcast_to(
                np.rint(column).astype(np.uint8)[:, None, :], (camera.height, camera.width, 3)
            )
        )
        return cls(
            objects=tuple(objects),
            texture=texture,
            texel_m=texel,
            x_min=-width_m / 2.0,
            z_max=far + 30.0,
            ground_y=camera_height_m,
            far_colour=(float(mean[0]), float(mean[1]), float(mean[2])),
            sky=sky,
            params=params,
        )

    def ground_view(
        self, camera: CameraModel, r_cw: npt.NDArray[np.float64], centre: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.uint8]:
        """BGR view of ground and sky from a camera at `centre` with world-to-camera `r_cw`."""
        # texel (u, v) -> world (x_min + u * texel, ground_y, z_max - v * texel)
        a = np.array(
            [
                [self.texel_m, 0.0, self.x_min],
                [0.0, 0.0, self.ground_y],
                [0.0, -self.texel_m, self.z_max],
            ]
        )
        a[:, 2] -= centre
        h = camera.matrix @ r_cw @ a
        view = np.asarray(
            cv2.warpPerspective(
                self.texture,
                h,
                camera.size,
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=self.far_colour,
            ),
            dtype=np.uint8,
        )
        # ground where the viewing ray points down (towards +y world): l . (x, y, 1) > 0
        normal = r_cw @ np.array([0.0, 1.0, 0.0])
        line = np.linalg.inv(camera.matrix).T @ normal
        w, hgt = camera.width, camera.height
        rect = [(-1.0, -1.0), (w + 1.0, -1.0), (w + 1.0, hgt + 1.0), (-1.0, hgt + 1.0)]
        sky_poly = _clip_halfplane(rect, line)
        if sky_poly:
            mask = np.zeros((hgt, w), dtype=np.uint8)
            pts = np.rint(np.array(sky_poly) * 16).astype(np.int32)
            cv2.fillPoly(mask, [pts], 255, cv2.LINE_8, shift=4)
            view = np.asarray(cv2.copyTo(self.sky, mask, view), dtype=np.uint8)
        return view


def _clip_halfplane(
    polygon: list[tuple[float, float]], line: npt.NDArray[np.float64]
) -> list[tuple[float, float]]:
    """Part of a convex polygon where line . (x, y, 1) <= 0 (Sutherland-Hodgman, one edge)."""
    out: list[tuple[float, float]] = []
    n = len(polygon)
    for i in range(n):
        p, q = polygon[i], polygon[(i + 1) % n]
        vp = line[0] * p[0] + line[1] * p[1] + line[2]
        vq = line[0] * q[0] + line[1] * q[1] + line[2]
        if vp <= 0:
            out.append(p)
        if (vp <= 0) != (vq <= 0):
            s = vp / (vp - vq)
            out.append((p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1])))
    return out
