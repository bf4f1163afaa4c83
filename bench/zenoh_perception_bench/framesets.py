"""The generated frame sets (:mod:`zenoh_perception_bench.scene`, exact ground truth) and how many
frames the bench makes of each (:class:`Plan`).

Every set has realistic effects (blur, motion blur, noise, lighting, clutter):

- ``VGA`` ... ``HD2K``: independent frames, 4 tags and 2 look-alikes each;
- ``video``: consecutive HD720 frames at 60 Hz (the ZED's HD720 rate) of a rover driving
  toward 4 tags and 2 look-alikes;
- ``distractors``: HD720 frames with 1 tag and 6 look-alikes;
- ``real-camera`` and ``real-camera video``: the same at HD720 with what real cameras add
  (:meth:`~zenoh_perception_bench.scene.Effects.real_camera`: colour casts, JPEG 4:2:0, exposure,
  shadows, glare, greyscale, rolling shutter, strong blur), a quarter of the tags cut by the
  border on every other independent frame;
- ``boards`` (:func:`board_frames`): HD720 frames with a checkerboard (straight, rotated, in
  perspective) or a tiled floor of 8-20 px squares over half the frame and tags beside it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from zenoh_perception.resolutions import RESOLUTIONS as SCENE_RESOLUTIONS
from zenoh_perception_bench.progress import Progress, tick
from zenoh_perception_bench.scene import CameraModel, Effects, Scene, SceneGenerator
from zenoh_perception_bench.scene.boards import BOARD_KINDS, board_scene

#: The independent frame sets: every named resolution of the scene generator.
RESOLUTIONS: Final = tuple(SCENE_RESOLUTIONS)
VIDEO_RESOLUTION: Final = "HD720"
#: The board case: square sizes (px) of the checkerboards beside tags, per kind of board.
BOARD_SQUARES: Final = (8, 10, 12, 14, 17, 20)
BOARD_SQUARES_QUICK: Final = (10, 16)


@dataclass(frozen=True, slots=True)
class Plan:
    """How much the bench measures (the defaults: the full bench)."""

    frames: int = 60  # independent frames per resolution
    video_frames: int = 300
    video_fps: float = 60.0
    distractor_frames: int = 40
    lookalike_frames: int = 4  # per family and look-alike kind (bench.lookalikes)
    throughput_s: float = 8.0
    seed: int = 2024
    # end to end: lockstep passes over the HD720 independent frames and over the video, each
    # with service processes of its own (one pass's figure varies from run to run on a shared
    # machine; the passes are pooled)
    e2e_passes: int = 3
    board_squares: tuple[int, ...] = BOARD_SQUARES
    busy_board_frames: int = 30  # sent at 5 Hz, a plain frame every tenth
    # per distance of the range figure (bench.reach): with 20, one draw more or less at a
    # distance moved OpenCV's range by 1 m between seeds
    range_frames: int = 60

    @classmethod
    def full(cls) -> Plan:
        return cls()

    @classmethod
    def quick(cls) -> Plan:
        return cls(
            frames=6,
            video_frames=24,
            distractor_frames=6,
            lookalike_frames=1,
            throughput_s=1.0,
            e2e_passes=2,
            board_squares=BOARD_SQUARES_QUICK,
            busy_board_frames=10,
            range_frames=4,
        )


@dataclass(frozen=True, slots=True)
class FrameSet:
    name: str
    resolution: str
    scenes: list[Scene]
    video: bool = False


def frame_sets(plan: Plan, progress: Progress | None) -> list[FrameSet]:
    """Independent frames per resolution, the video drive, the look-alike frames, and the
    real-camera independent frames and drive."""
    sets: list[FrameSet] = []

    def add(name: str, scenes: Iterable[Scene], resolution: str, *, video: bool = False) -> None:
        collected = []
        for scene in scenes:
            collected.append(scene)
            tick(progress, f"scenes {name}")
        sets.append(FrameSet(name, resolution, collected, video))

    def generator(resolution: str, seed_offset: int, effects: Effects) -> SceneGenerator:
        camera = CameraModel.named(resolution)
        return SceneGenerator(camera, seed=plan.seed + seed_offset, effects=effects)

    def drive(scenes: SceneGenerator) -> Iterable[Scene]:
        return scenes.drive(plan.video_frames, fps=plan.video_fps, n_tags=4, n_distractors=2)

    for offset, resolution in enumerate(RESOLUTIONS):
        scenes = generator(resolution, offset, Effects.realistic())
        add(resolution, (scenes.random_scene(4, 2) for _ in range(plan.frames)), resolution)
    video = generator(VIDEO_RESOLUTION, 10, Effects.realistic())
    add("video", drive(video), VIDEO_RESOLUTION, video=True)
    lookalikes = generator(VIDEO_RESOLUTION, 20, Effects.realistic())
    add(
        "distractors",
        (lookalikes.random_scene(1, 6) for _ in range(plan.distractor_frames)),
        VIDEO_RESOLUTION,
    )
    real = generator(VIDEO_RESOLUTION, 40, Effects.real_camera())
    # every other frame has a quarter of its tags cut by the border
    add(
        "real-camera",
        (
            real.random_scene(4, 2, partial_fraction=0.25 if index % 2 else 0.0)
            for index in range(plan.frames)
        ),
        VIDEO_RESOLUTION,
    )
    real_drive = generator(VIDEO_RESOLUTION, 50, Effects.real_camera())
    add("real-camera video", drive(real_drive), VIDEO_RESOLUTION, video=True)
    return sets


@dataclass(frozen=True, slots=True)
class BoardFrame:
    """An HD720 frame with a board of ``kind`` and ``square`` px over its left half and the
    tags ``ids`` beside it."""

    kind: str
    square: int
    image: npt.NDArray[np.uint8]
    ids: frozenset[int]


def board_frames(plan: Plan) -> list[BoardFrame]:
    """Every kind of board at every square size of ``plan``."""
    width, height = SCENE_RESOLUTIONS[VIDEO_RESOLUTION]
    squares, seed = plan.board_squares, plan.seed
    frames = []
    for index, (kind, square) in enumerate(
        (kind, square) for kind in BOARD_KINDS for square in squares
    ):
        scene = board_scene(width, height, square, kind, seed=seed + index)
        ids = frozenset(tag_id for tag_id, _ in scene.markers)
        frames.append(BoardFrame(kind, square, scene.image, ids))
    return frames
