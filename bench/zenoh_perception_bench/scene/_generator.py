"""Scenes with exact ground truth: random independent frames and a rover "drive" video."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception_bench.scene._camera_effects import (
    Light,
    camera_output,
    light_scene,
    plan_tag_light,
    rolling_shutter,
    shear_points,
)
from zenoh_perception_bench.scene._distractors import (
    CODE_DISTRACTOR_KINDS,
    check_kinds,
    plate_ratio,
    render_distractor,
)
from zenoh_perception_bench.scene._effects import (
    EffectParams,
    Effects,
    apply_effects,
    background,
    draw_clutter,
)
from zenoh_perception_bench.scene._errors import SceneError
from zenoh_perception_bench.scene._geometry import (
    R_FACING,
    CameraModel,
    MarkerPose,
    f64,
    facing_rotation,
    in_front,
    rodrigues,
    rot_x,
    rot_y,
    rot_z,
    rvec_of,
    square_corners,
)
from zenoh_perception_bench.scene._raster import (
    dictionary_size,
    homography,
    marker_cells,
    marker_patch,
    paste,
    to_bgra,
)
from zenoh_perception_bench.scene._truth import (
    DistractorTruth,
    MarkerTruth,
    Scene,
    Truth,
    frozen,
)
from zenoh_perception_bench.scene._world import World, WorldObject

_PLACEMENT_ATTEMPTS = 300
_OVERLAP_GROWTH = 1.12


@dataclass(frozen=True)
class DistractorPose:
    """A distractor placed in the camera frame: `size_m` is the side of its dark core square;
    `rvec` as in `MarkerPose` (None: upright, facing the camera)."""

    kind: str
    size_m: float
    position: tuple[float, float, float]
    rvec: tuple[float, float, float] | None = None
    mimic_id: int | None = None

    def __post_init__(self) -> None:
        check_kinds((self.kind,))
        if not self.size_m > 0:
            raise SceneError(f"size_m must be > 0, got {self.size_m}")
        if len(self.position) != 3 or not all(math.isfinite(v) for v in self.position):
            raise SceneError(f"position must be 3 finite numbers, got {self.position!r}")
        if (self.kind in CODE_DISTRACTOR_KINDS) != (self.mimic_id is not None):
            raise SceneError(f"kind {self.kind!r} needs mimic_id only if it hides a code")

    @property
    def rotation(self) -> npt.NDArray[np.float64]:
        """Object-to-camera rotation."""
        return R_FACING.copy() if self.rvec is None else rodrigues(self.rvec)


@dataclass(frozen=True)
class _Placement:
    """Ranges for random placement."""

    size_m: tuple[float, float]
    distance_m: tuple[float, float]
    max_tilt_deg: float
    max_roll_deg: float
    side_px: tuple[float, float] | None = None


@dataclass
class _Item:
    """An object ready to draw: pose in the camera frame and its projected footprint."""

    depth: float
    footprint: npt.NDArray[np.float64]  # (4, 2) outer outline incl. quiet zone / plate
    marker: MarkerPose | None = None
    distractor: DistractorPose | None = None
    ratio: float = 1.0
    seed: int | None = None  # fixed art / ink across frames (drive); None: scene generator


def _quad_overlap(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> bool:
    area, _ = cv2.intersectConvexConvex(a.astype(np.float32), b.astype(np.float32))
    return bool(area > 0.0)


def _grow(quad: npt.NDArray[np.float64], factor: float, pad_px: float) -> npt.NDArray[np.float64]:
    centre = quad.mean(axis=0)
    d = quad - centre
    n = np.linalg.norm(d, axis=1, keepdims=True)
    out: npt.NDArray[np.float64] = centre + d * factor + d / np.maximum(n, 1e-9) * pad_px
    return out


def _intersects_image(quad: npt.NDArray[np.float64], camera: CameraModel) -> bool:
    rect = np.array(
        [
            [-0.5, -0.5],
            [camera.width - 0.5, -0.5],
            [camera.width - 0.5, camera.height - 0.5],
            [-0.5, camera.height - 0.5],
        ]
    )
    if (
        quad[:, 0].max() < -0.5
        or quad[:, 0].min() > camera.width - 0.5
        or quad[:, 1].max() < -0.5
        or quad[:, 1].min() > camera.height - 0.5
    ):
        return False
    return _quad_overlap(quad, rect)


class SceneGenerator:
    """Deterministic synthetic scenes for one camera.

    All randomness comes from one numpy Generator seeded with `seed`, so the sequence of scenes
    returned by successive calls is a pure function of the seed and the call arguments.
    """

    def __init__(
        self,
        camera: CameraModel,
        *,
        dictionary: str = "DICT_4X4_50",
        seed: int | None = 0,
        effects: Effects | None = None,
        quiet_zone_bits: int = 1,
    ) -> None:
        if quiet_zone_bits < 0:
            raise SceneError(f"quiet_zone_bits must be >= 0, got {quiet_zone_bits}")
        self.camera = camera
        self.dictionary = dictionary
        self.effects = Effects() if effects is None else effects
        self.quiet_zone_bits = quiet_zone_bits
        self._n_ids = dictionary_size(dictionary)  # validates the name
        self._cells = int(marker_cells(dictionary, 0).shape[0])
        self._rng = np.random.default_rng(seed)

    # ------------------------------------------------------------------ public API

    def random_scene(
        self,
        n_markers: int = 3,
        n_distractors: int = 0,
        *,
        ids: Sequence[int] | None = None,
        size_m: tuple[float, float] = (0.1, 0.3),
        distance_m: tuple[float, float] = (0.5, 8.0),
        max_tilt_deg: float = 50.0,
        max_roll_deg: float = 180.0,
        partial_fraction: float = 0.0,
        distractor_kinds: Sequence[str] = CODE_DISTRACTOR_KINDS,
        side_px: tuple[float, float] | None = None,
    ) -> Scene:
        """An independent frame with up to `n_markers` tags and `n_distractors` look-alikes.

        Distances are drawn log-uniform in `distance_m`, sizes uniform in `size_m` (before
        rejecting poses that do not fit, which thins out the largest near ones). With
        `side_px` (min, max) the side of each object's square in pixels is drawn log-uniform
        there instead (within a few percent; tilt changes the shape, not the mean side) and its
        distance follows from its size, so `distance_m` is not used. Each object is
        tilted away from the line of sight by up to `max_tilt_deg` (random axis) and turned in
        plane by up to +-`max_roll_deg`. Objects never overlap (quiet zones and plates
        included). Tags are fully inside the frame, except a `partial_fraction` of them that
        straddle the border. Ids are distinct, random unless `ids` is given. An object that
        cannot be placed after a few hundred attempts is left out (only with crowded frames).
        """
        kinds = tuple(distractor_kinds)
        if n_distractors > 0:
            check_kinds(kinds)
        self._check_counts(n_markers, n_distractors, size_m, distance_m)
        if not 0.0 <= partial_fraction <= 1.0:
            raise SceneError(f"partial_fraction must be in [0, 1], got {partial_fraction}")
        if not (0.0 <= max_tilt_deg <= 85.0 and 0.0 <= max_roll_deg <= 180.0):
            raise SceneError("need 0 <= max_tilt_deg <= 85 and 0 <= max_roll_deg <= 180")
        if side_px is not None and not (0.0 < side_px[0] <= side_px[1]):
            raise SceneError(f"side_px must be (min, max) with 0 < min <= max, got {side_px}")
        chosen = self._choose_ids(n_markers, ids)
        rng = self._rng
        params = self.effects.sample(rng)
        canvas = background(params.background, self.camera.width, self.camera.height, rng)
        draw_clutter(canvas, params.clutter, rng)

        order = [("m", i) for i in range(n_markers)] + [("d", i) for i in range(n_distractors)]
        rng.shuffle(order)
        items: list[_Item] = []
        placed: list[npt.NDArray[np.float64]] = []
        spec = _Placement(size_m, distance_m, max_tilt_deg, max_roll_deg, side_px)
        for what, i in order:
            if what == "m":
                partial = bool(rng.random() < partial_fraction)
                item = self._place(rng, placed, spec, partial=partial, marker_id=chosen[i])
            else:
                kind = kinds[int(rng.integers(len(kinds)))]
                item = self._place(rng, placed, spec, kind=kind)
            if item is not None:
                items.append(item)
                placed.append(_grow(item.footprint, _OVERLAP_GROWTH, 2.0))
        return self._finish(canvas, items, params, rng, index=0, time_s=0.0, occlusion=False)

    def scene_from_poses(
        self,
        markers: Sequence[MarkerPose],
        distractors: Sequence[DistractorPose] = (),
    ) -> Scene:
        """Render given poses (camera frame) with this generator's effects and background.

        Objects behind the camera or entirely outside the image are left out of the scene and
        its truth. Drawn far to near; overlaps are flagged as `occluded`.
        """
        rng = self._rng
        params = self.effects.sample(rng)
        canvas = background(params.background, self.camera.width, self.camera.height, rng)
        draw_clutter(canvas, params.clutter, rng)
        items: list[_Item] = []
        for pose in markers:
            self._check_marker_id(pose.tag_id)
            item = self._marker_item(pose)
            if item is not None:
                items.append(item)
        for dpose in distractors:
            if dpose.mimic_id is not None:
                self._check_marker_id(dpose.mimic_id)
            ratio = plate_ratio(dpose.kind, rng)
            item = self._distractor_item(dpose, ratio)
            if item is not None:
                items.append(item)
        return self._finish(canvas, items, params, rng, index=0, time_s=0.0, occlusion=True)

    def drive(
        self,
        n_frames: int,
        fps: float = 15.0,
        speed_mps: float = 1.0,
        *,
        n_tags: int = 4,
        n_distractors: int = 2,
        ids: Sequence[int] | None = None,
        size_m: tuple[float, float] = (0.15, 0.3),
        shake_deg: float = 0.3,
        camera_height_m: float = 0.6,
        distractor_kinds: Sequence[str] = CODE_DISTRACTOR_KINDS,
    ) -> Iterator[Scene]:
        """Frames of a rover driving forward over textured ground past fixed tags on posts.

        The camera starts at the world origin (world axes = initial camera axes: x right,
        y down, z forward), `camera_height_m` above flat ground, and moves along +z at
        `speed_mps` with a gentle weave and a smooth random shake of about `shake_deg`.
        Tags (and `n_distractors` look-alikes) stand 3 m to (travel + 7) m ahead, 0.3-1.6 m
        to the side, roughly facing the rover; they grow, and leave the frame as it passes.
        Effect values are drawn once for the whole drive (noise is fresh every frame;
        `Effects.clutter` sets the number of extra shapes on the ground texture).
        """
        if n_frames < 0 or not fps > 0 or speed_mps < 0:
            raise SceneError("need n_frames >= 0, fps > 0 and speed_mps >= 0")
        if not camera_height_m > 0 or shake_deg < 0:
            raise SceneError("need camera_height_m > 0 and shake_deg >= 0")
        kinds = tuple(distractor_kinds)
        if n_distractors > 0:
            check_kinds(kinds)
        self._check_counts(n_tags, n_distractors, size_m, (1.0, 2.0))
        chosen = self._choose_ids(n_tags, ids)
        world = World.build(
            self._rng,
            self.camera,
            self.effects,
            ids=chosen,
            n_distractors=n_distractors,
            kinds=kinds,
            size_m=size_m,
            travel_m=speed_mps * n_frames / fps,
            camera_height_m=camera_height_m,
            n_ids=self._n_ids,
        )
        return self._drive_frames(world, n_frames, fps, speed_mps, shake_deg)

    # ------------------------------------------------------------------ internals

    def _check_marker_id(self, tag_id: int) -> None:
        if not 0 <= tag_id < self._n_ids:
            raise SceneError(f"tag id {tag_id} out of range for {self.dictionary}")

    def _check_counts(
        self,
        n_markers: int,
        n_distractors: int,
        size_m: tuple[float, float],
        distance_m: tuple[float, float],
    ) -> None:
        if n_markers < 0 or n_distractors < 0:
            raise SceneError("object counts must be >= 0")
        if not (0 < size_m[0] <= size_m[1]):
            raise SceneError(f"size_m must be (min, max) with 0 < min <= max, got {size_m}")
        if not (0 < distance_m[0] <= distance_m[1]):
            raise SceneError(f"distance_m must be (min, max), 0 < min <= max, got {distance_m}")

    def _choose_ids(self, n: int, ids: Sequence[int] | None) -> list[int]:
        if ids is None:
            if n > self._n_ids:
                raise SceneError(f"{self.dictionary} has only {self._n_ids} ids, asked for {n}")
            return [int(i) for i in self._rng.choice(self._n_ids, size=n, replace=False)]
        chosen = [int(i) for i in ids]
        if len(chosen) != n:
            raise SceneError(f"got {len(chosen)} ids for {n} markers")
        for tag_id in chosen:
            self._check_marker_id(tag_id)
        return chosen

    def _footprint_scale(self) -> float:
        return (self._cells + 2 * self.quiet_zone_bits) / self._cells

    def _marker_item(self, pose: MarkerPose) -> _Item | None:
        outline = pose.corners_3d(pose.size_m * self._footprint_scale())
        if not in_front(outline):
            return None
        footprint = self.camera.project(outline)
        if not _intersects_image(footprint, self.camera):
            return None
        return _Item(float(np.linalg.norm(pose.position)), footprint, marker=pose)

    def _distractor_item(self, pose: DistractorPose, ratio: float) -> _Item | None:
        outline = square_corners(pose.size_m * ratio) @ pose.rotation.T + f64(pose.position)
        if not in_front(outline):
            return None
        footprint = self.camera.project(outline)
        if not _intersects_image(footprint, self.camera):
            return None
        depth = float(np.linalg.norm(pose.position))
        return _Item(depth, footprint, distractor=pose, ratio=ratio)

    def _place(
        self,
        rng: np.random.Generator,
        placed: list[npt.NDArray[np.float64]],
        spec: _Placement,
        *,
        partial: bool = False,
        marker_id: int | None = None,
        kind: str | None = None,
    ) -> _Item | None:
        cam = self.camera
        log_lo, log_hi = math.log(spec.distance_m[0]), math.log(spec.distance_m[1])
        ratio = 1.0 if kind is None else plate_ratio(kind, rng)
        mimic = None
        if kind is not None and kind != "decoy":
            mimic = int(rng.integers(self._n_ids))
        for _ in range(_PLACEMENT_ATTEMPTS):
            # with side_px, the first draw is the side in pixels instead of the distance
            if spec.side_px is None:
                dist = math.exp(float(rng.uniform(log_lo, log_hi)))
            else:
                lo_px, hi_px = spec.side_px
                side = math.exp(float(rng.uniform(math.log(lo_px), math.log(hi_px))))
            size = float(rng.uniform(spec.size_m[0], spec.size_m[1]))
            pixel = (rng.uniform(0, cam.width - 1), rng.uniform(0, cam.height - 1))
            direction = cam.ray(pixel)
            tilt = math.radians(float(rng.uniform(0.0, spec.max_tilt_deg)))
            axis_angle = float(rng.uniform(0.0, 2 * math.pi))
            axis = np.array([math.cos(axis_angle), math.sin(axis_angle), 0.0]) * tilt
            roll = float(rng.uniform(-spec.max_roll_deg, spec.max_roll_deg))
            rotation = facing_rotation(direction) @ rodrigues(axis) @ rot_z(roll)
            if spec.side_px is not None:
                dist = self._distance_for_side(size, side, direction, rotation)
            position = direction * dist
            pos = (float(position[0]), float(position[1]), float(position[2]))
            rvec = rvec_of(rotation)
            rv = (float(rvec[0]), float(rvec[1]), float(rvec[2]))
            if marker_id is not None:
                item = self._marker_item(MarkerPose(marker_id, size, pos, rvec=rv))
            else:
                dpose = DistractorPose(str(kind), size, pos, rv, mimic)
                item = self._distractor_item(dpose, ratio)
            if item is None:
                continue
            if partial and item.marker is not None:
                corners = cam.project(item.marker.corners_3d())
                if cam.contains(corners) or not cam.contains(corners.mean(axis=0)):
                    continue
            elif not cam.contains(item.footprint, margin=1.0):
                continue
            grown = _grow(item.footprint, _OVERLAP_GROWTH, 2.0)
            if any(_quad_overlap(grown, other) for other in placed):
                continue
            return item
        return None

    def _distance_for_side(
        self,
        size: float,
        side: float,
        direction: npt.NDArray[np.float64],
        rotation: npt.NDArray[np.float64],
    ) -> float:
        """Distance along `direction` at which a square of `size` metres turned by `rotation`
        has a mean side of about `side` pixels: the pinhole estimate, corrected once by the
        side it projects to there (the projected side scales with the inverse distance)."""
        guess = self.camera.fx * size / side
        square = square_corners(size) @ rotation.T + direction * guess
        if not in_front(square):
            return guess
        quad = self.camera.project(square)
        measured = float(np.linalg.norm(np.roll(quad, -1, axis=0) - quad, axis=1).mean())
        return guess * measured / side

    def _finish(
        self,
        canvas: npt.NDArray[np.uint8],
        items: list[_Item],
        params: EffectParams,
        rng: np.random.Generator,
        *,
        index: int,
        time_s: float,
        occlusion: bool,
    ) -> Scene:
        """Draw items far to near, apply effects, build truth."""
        items = sorted(items, key=lambda it: -it.depth)
        markers: list[MarkerTruth] = []
        distractors: list[DistractorTruth] = []
        camera = params.camera
        lights: list[Light] = []
        for n, item in enumerate(items):
            occluded = occlusion and any(
                _quad_overlap(item.footprint, nearer.footprint) for nearer in items[n + 1 :]
            )
            art_rng = rng if item.seed is None else np.random.default_rng(item.seed)
            if item.marker is not None:
                truth = self._draw_marker(canvas, item.marker, art_rng, occluded)
                markers.append(truth)
                if camera.enabled:
                    lights += plan_tag_light(camera, truth.corners, item.footprint, art_rng)
            elif item.distractor is not None:
                distractors.append(self._draw_distractor(canvas, item, art_rng))
        if camera.enabled:
            canvas = light_scene(canvas, camera, lights, rng)
            canvas = rolling_shutter(canvas, camera.rolling_shutter_px)
            markers = [self._sheared(m, camera.rolling_shutter_px) for m in markers]
            distractors = [self._sheared(d, camera.rolling_shutter_px) for d in distractors]
        effected = apply_effects(canvas, params, rng)
        if camera.enabled:
            effected = camera_output(effected, camera)
        image = to_bgra(effected)
        markers.sort(key=lambda m: m.tag_id)
        return Scene(
            image=image,
            camera=self.camera,
            markers=tuple(markers),
            distractors=tuple(distractors),
            effects=params,
            dictionary=self.dictionary,
            index=index,
            time_s=time_s,
        )

    def _sheared(self, truth: Truth, shift_px: float) -> Truth:
        """`truth` with corners and centre where the rolling shutter moved them (the pose is
        the one at the middle row's readout)."""
        if abs(shift_px) < 1e-3:
            return truth
        corners = shear_points(truth.corners, shift_px, self.camera.height)
        centre = shear_points(truth.centre, shift_px, self.camera.height)[0]
        return replace(
            truth,
            corners=frozen(corners),
            centre=frozen(centre),
            visible=self.camera.contains(corners),
        )

    def _draw_marker(
        self,
        canvas: npt.NDArray[np.uint8],
        pose: MarkerPose,
        rng: np.random.Generator,
        occluded: bool,
    ) -> MarkerTruth:
        corners = self.camera.project(pose.corners_3d())
        black, white = self.effects.ink(rng)
        patch, border = marker_patch(
            self.dictionary, pose.tag_id, self.quiet_zone_bits, black, white
        )
        paste(canvas, patch, homography(border, corners), pixel_art=True)
        tvec = pose.tvec
        return MarkerTruth(
            tag_id=pose.tag_id,
            corners=frozen(corners),
            centre=frozen(self.camera.project(tvec)[0]),
            distance_m=float(np.linalg.norm(tvec)),
            size_m=pose.size_m,
            rvec=frozen(rvec_of(pose.rotation)),
            tvec=frozen(tvec),
            visible=self.camera.contains(corners),
            occluded=occluded,
        )

    def _draw_distractor(
        self, canvas: npt.NDArray[np.uint8], item: _Item, rng: np.random.Generator
    ) -> DistractorTruth:
        pose = item.distractor
        if pose is None:  # pragma: no cover - guarded by the caller
            raise SceneError("not a distractor item")
        rotation = pose.rotation
        position = f64(pose.position)
        corners = self.camera.project(square_corners(pose.size_m) @ rotation.T + position)
        side = float(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1).max())
        art = render_distractor(
            pose.kind, self.dictionary, pose.mimic_id, side_px=side, ratio=item.ratio, rng=rng
        )
        paste(canvas, art.patch, homography(art.core, corners), pixel_art=False)
        return DistractorTruth(
            kind=pose.kind,
            corners=frozen(corners),
            centre=frozen(self.camera.project(position)[0]),
            distance_m=float(np.linalg.norm(position)),
            size_m=pose.size_m,
            mimic_id=pose.mimic_id,
            visible=self.camera.contains(corners),
        )

    def _drive_frames(
        self, world: World, n_frames: int, fps: float, speed_mps: float, shake_deg: float
    ) -> Iterator[Scene]:
        rng = self._rng
        # per axis (yaw, pitch, roll): three sinusoids, scaled to an RMS of shake_deg
        freqs = rng.uniform(0.6, 3.0, (3, 3))
        phases = rng.uniform(0.0, 2 * math.pi, (3, 3))
        amps = rng.uniform(0.3, 1.0, (3, 3))
        amps *= shake_deg / np.sqrt(np.sum(amps**2, axis=1, keepdims=True) / 2.0)
        weave_amp = float(rng.uniform(0.0, 0.25)) if speed_mps > 0 else 0.0
        weave_w = 2 * math.pi / float(rng.uniform(6.0, 14.0))
        weave_phase = float(rng.uniform(0, 2 * math.pi))
        for i in range(n_frames):
            t = i / fps
            yaw, pitch, roll = np.sum(amps * np.sin(2 * math.pi * freqs * t + phases), axis=1)
            x = weave_amp * math.sin(weave_w * t + weave_phase)
            heading = 0.0
            if speed_mps > 0:
                slope = weave_amp * weave_w * math.cos(weave_w * t + weave_phase) / speed_mps
                heading = math.degrees(math.atan(slope))
            bob = 0.004 * math.sin(2 * math.pi * 2.3 * t)
            centre = np.array([x, bob, speed_mps * t])
            r_wc = rot_y(heading + float(yaw)) @ rot_x(float(pitch)) @ rot_z(float(roll))
            canvas = world.ground_view(self.camera, r_wc.T, centre)
            for obj in world.objects:
                self._draw_post(canvas, obj, world.ground_y, r_wc.T, centre)
            items = [
                item
                for item in (self._world_item(obj, r_wc.T, centre) for obj in world.objects)
                if item is not None
            ]
            yield self._finish(canvas, items, world.params, rng, index=i, time_s=t, occlusion=True)

    def _draw_post(
        self,
        canvas: npt.NDArray[np.uint8],
        obj: WorldObject,
        ground_y: float,
        r_cw: npt.NDArray[np.float64],
        centre: npt.NDArray[np.float64],
    ) -> None:
        """A thin pole from just behind the object's centre down to the ground."""
        top = obj.position - obj.rotation[:, 2] * 0.02
        half = np.array([0.02, 0.0, 0.0])
        bottom = np.array([top[0], ground_y, top[2]])
        world = np.stack([top - half, top + half, bottom + half, bottom - half])
        cam = (world - centre) @ r_cw.T
        if not in_front(cam):
            return
        pix = self.camera.project(cam)
        if not _intersects_image(pix, self.camera):
            return
        pts = np.rint(pix * 16).astype(np.int32)
        cv2.fillPoly(canvas, [pts], obj.post_colour, cv2.LINE_AA, shift=4)

    def _world_item(
        self, obj: WorldObject, r_cw: npt.NDArray[np.float64], centre: npt.NDArray[np.float64]
    ) -> _Item | None:
        t = r_cw @ (obj.position - centre)
        position = (float(t[0]), float(t[1]), float(t[2]))
        rv = rvec_of(r_cw @ obj.rotation)
        rvec = (float(rv[0]), float(rv[1]), float(rv[2]))
        if obj.tag_id >= 0:
            item = self._marker_item(MarkerPose(obj.tag_id, obj.size_m, position, rvec=rvec))
        else:
            dpose = DistractorPose(obj.kind, obj.size_m, position, rvec, obj.mimic_id)
            item = self._distractor_item(dpose, obj.ratio)
        if item is not None:
            item.seed = obj.seed
        return item
