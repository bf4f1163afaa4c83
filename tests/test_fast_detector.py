"""The project's detector on generated scenes: ids, corners, look-alikes, tracking, dictionaries."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.detect import MarkerModel, fit_marker, refine_corners
from zenoh_perception.detection import Detection, OpenCvDetector, aruco_dictionary, make_detector
from zenoh_perception.errors import SettingsError
from zenoh_perception.fast_detector import FastDetector, FastDetectorConfig
from zenoh_perception.pose import Intrinsics, estimate_pose
from zenoh_perception.scene import (
    CameraModel,
    DistractorPose,
    Effects,
    MarkerPose,
    Scene,
    SceneGenerator,
    render_markers,
)

Gray = npt.NDArray[np.uint8]


def _gray(scene_or_image: Scene | npt.NDArray[np.uint8]) -> Gray:
    image = scene_or_image.image if isinstance(scene_or_image, Scene) else scene_or_image
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)


def _square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _by_id(detections: list[Detection]) -> dict[int, npt.NDArray[np.float32]]:
    return {d.tag_id: d.corners for d in detections}


# ------------------------------------------------------------------ ids and corners


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_generated_scenes_ids_and_corners(seed: int) -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=seed, effects=Effects.realistic())
    detector = FastDetector()
    for _ in range(4):
        scene = generator.random_scene(4, 0, size_m=(0.12, 0.3), distance_m=(0.6, 3.0))
        found = _by_id(detector.detect(_gray(scene)))
        truth = {m.tag_id: m for m in scene.markers}
        assert set(found) <= set(truth)  # nothing that is not a marker
        for marker in scene.markers:
            if not marker.visible or marker.occluded or marker.side_px < 24:
                continue
            assert marker.tag_id in found, f"missed tag {marker.tag_id} of {marker.side_px:.0f} px"
            error = np.abs(found[marker.tag_id] - marker.corners).max()
            assert error < 0.5, f"tag {marker.tag_id}: corner error {error:.2f} px"


def test_exact_quads_are_refined_to_a_few_hundredths_of_a_pixel() -> None:
    rng = np.random.default_rng(5)
    for _ in range(6):
        side = float(rng.uniform(30, 160))
        x0, y0 = rng.uniform(30, 640 - side - 30), rng.uniform(30, 480 - side - 30)
        angle = float(rng.uniform(0, np.pi / 2))
        centre = np.array([x0 + side / 2, y0 + side / 2])
        rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        quad = centre + (_square(0, 0, side) - side / 2) @ rot.T * 0.7
        tag = int(rng.integers(50))
        image = render_markers(640, 480, [(tag, quad)], background=200)
        found = _by_id(FastDetector().detect(_gray(image)))
        assert list(found) == [tag]
        assert np.abs(found[tag] - quad).max() < 0.06


def test_refine_corners_recovers_a_perturbed_quad_and_measures_blur() -> None:
    quad = _square(100.3, 80.6, 120.0)
    image = render_markers(400, 300, [(3, quad)], background=230)
    gray = np.asarray(cv2.GaussianBlur(_gray(image), (0, 0), 1.2), dtype=np.uint8)
    refined = refine_corners(
        gray, quad + np.array([[1.5, -1.0], [-1.2, 0.8], [1.0, 1.1], [-0.7, -1.4]]), 6
    )
    assert refined is not None
    assert np.abs(refined.corners - quad).max() < 0.05
    assert refined.blur_px == pytest.approx(1.2 * 1.1, rel=0.25)  # + bilinear sampling
    # no edge to measure: flat image
    assert refine_corners(np.full((300, 400), 128, np.uint8), quad, 6) is None


# ------------------------------------------------------------------ look-alikes


@pytest.mark.parametrize("kind", ["blob", "glyph", "bare_code"])
def test_look_alikes_that_opencv_decodes_are_rejected(kind: str) -> None:
    generator = SceneGenerator(CameraModel.named("HD720"), seed=3, effects=Effects.realistic())
    baseline = OpenCvDetector()
    fooled = 0
    for row in range(3):
        poses = [
            DistractorPose(kind, 0.2, (x, -0.45 + 0.25 * row, 1.6), mimic_id=(7 * row + i) % 50)
            for i, x in enumerate((-0.6, 0.0, 0.6))
        ]
        scene = generator.scene_from_poses([MarkerPose(44, 0.15, (0.0, 0.55, 2.0))], poses)
        gray = _gray(scene)
        fooled += sum(d.tag_id != 44 for d in baseline.detect(gray))
        found = _by_id(FastDetector().detect(gray))
        assert list(found) == [44], f"{kind}: reported {sorted(found)}"
    assert fooled > 0  # the scenes do fool OpenCV's default detector


def test_model_fit_scores_real_markers_far_below_look_alikes() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=9, effects=Effects.clean())
    scene = generator.scene_from_poses(
        [MarkerPose(10, 0.2, (-0.25, 0.0, 1.0))],
        [DistractorPose("glyph", 0.2, (0.25, 0.0, 1.0), mimic_id=12)],
    )
    gray = _gray(scene)
    model = MarkerModel(aruco_dictionary("DICT_4X4_50"))
    real = fit_marker(gray, scene.markers[0].corners, 10, model)
    fake = fit_marker(gray, scene.distractors[0].corners, 12, model)
    assert real.score < 0.03
    assert fake.score > 0.08
    assert real.contrast > 150


# ------------------------------------------------------------------ tracking


def _static_frames(poses_per_frame: list[list[MarkerPose]], seed: int = 4) -> list[Gray]:
    """Frames of a still camera over one fixed background (noise differs per frame)."""
    camera = CameraModel.named("VGA")
    effects = Effects(noise_sigma=(2.0, 2.0), blur_sigma=(0.5, 0.5))
    frames = []
    for poses in poses_per_frame:
        generator = SceneGenerator(camera, seed=seed, effects=effects)
        frames.append(_gray(generator.scene_from_poses(poses)))
    return frames


def test_a_new_tag_is_found_within_the_full_scan_period() -> None:
    config = FastDetectorConfig(full_scan_period=4)
    first = MarkerPose(1, 0.15, (-0.3, 0.0, 1.5))
    second = MarkerPose(2, 0.15, (0.3, 0.1, 1.5))
    for appear_at in range(1, 6):
        frames = _static_frames([[first]] * appear_at + [[first, second]] * 5)
        detector = FastDetector(config=config)
        seen = [{d.tag_id for d in detector.detect(frame)} for frame in frames]
        assert all(1 in ids for ids in seen)
        found_at = next(i for i, ids in enumerate(seen) if 2 in ids)
        assert appear_at <= found_at < appear_at + config.full_scan_period
        assert detector.stats.scene_cuts == 0  # the same scene all along: found by a scan


def test_a_tag_that_disappears_is_not_reported_on_the_next_frame() -> None:
    one = MarkerPose(1, 0.15, (-0.3, 0.0, 1.5))
    two = MarkerPose(2, 0.15, (0.3, 0.1, 1.5))
    frames = _static_frames([[one, two]] * 3 + [[one]] * 3)
    detector = FastDetector()
    seen = [sorted(d.tag_id for d in detector.detect(frame)) for frame in frames]
    assert seen == [[1, 2]] * 3 + [[1]] * 3


def test_a_tag_replaced_by_another_at_the_same_place_is_reported_at_once() -> None:
    # same border, same place: only the code changes (the thumbnail sees no scene cut)
    a = MarkerPose(1, 0.15, (-0.1, 0.0, 1.2))
    b = MarkerPose(2, 0.15, (-0.1, 0.0, 1.2))
    other = MarkerPose(3, 0.15, (0.35, 0.1, 1.5))
    frames = _static_frames([[a, other]] * 3 + [[b, other]] * 3)
    detector = FastDetector()
    seen = [sorted(d.tag_id for d in detector.detect(frame)) for frame in frames]
    assert seen == [[1, 3]] * 3 + [[2, 3]] * 3
    assert detector.stats.scene_cuts == 0


def test_tracking_follows_a_drive_without_losing_recall() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=21, effects=Effects.realistic())
    frames = list(generator.drive(30, fps=30.0, n_tags=3, n_distractors=0))
    tracking = FastDetector()
    scanning = FastDetector(config=FastDetectorConfig(track=False))
    hits = {"tracking": 0, "scanning": 0}
    for scene in frames:
        gray = _gray(scene)
        truth = {m.tag_id for m in scene.markers if m.visible and not m.occluded}
        tracked_ids = {d.tag_id for d in tracking.detect(gray)}
        scanned_ids = {d.tag_id for d in scanning.detect(gray)}
        assert tracked_ids <= {m.tag_id for m in scene.markers}
        hits["tracking"] += len(truth & tracked_ids)
        hits["scanning"] += len(truth & scanned_ids)
    assert hits["tracking"] >= hits["scanning"] > 0
    assert tracking.stats.full_scans < len(frames)  # most frames were tracked, not scanned
    assert tracking.stats.followed_direct + tracking.stats.followed_roi > 0
    assert scanning.stats.full_scans == len(frames)


@pytest.mark.parametrize(
    ("code", "to_rgb"), [(cv2.COLOR_BGRA2GRAY, False), (cv2.COLOR_RGB2GRAY, True)]
)
def test_converting_only_what_is_read_gives_the_grey_frame_result(code: int, to_rgb: bool) -> None:
    """detect_converting(colour) == detect(grey) frame by frame, on a drive (followed frames
    convert only the regions around the tracks) and then on unrelated frames (full scans)."""
    generator = SceneGenerator(CameraModel.named("VGA"), seed=23, effects=Effects.realistic())
    scenes = [*generator.drive(40, fps=30.0, n_tags=3, n_distractors=1)]
    scenes += [generator.random_scene(3, 1) for _ in range(3)]
    grey, converting = FastDetector(), FastDetector()
    for scene in scenes:
        colour = np.asarray(
            cv2.cvtColor(scene.image, cv2.COLOR_BGRA2RGB) if to_rgb else scene.image, np.uint8
        )
        expected = grey.detect(_gray(scene))
        found = converting.detect_converting(colour, code)
        assert [d.tag_id for d in found] == [d.tag_id for d in expected]
        for a, b in zip(found, expected, strict=True):
            np.testing.assert_array_equal(a.corners, b.corners)
    assert converting.stats.full_scans == grey.stats.full_scans < len(scenes)  # some followed
    assert converting.stats.followed_direct == grey.stats.followed_direct > 0


def test_unrelated_frames_are_each_fully_scanned() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=31, effects=Effects.realistic())
    scenes = [generator.random_scene(3, 0, distance_m=(0.6, 2.0)) for _ in range(5)]
    detector = FastDetector()
    for scene in scenes:
        found = {d.tag_id for d in detector.detect(_gray(scene))}
        expected = {m.tag_id for m in scene.markers if m.visible and not m.occluded}
        assert expected <= found <= {m.tag_id for m in scene.markers}
    assert detector.stats.full_scans == len(scenes)
    assert detector.stats.scene_cuts == len(scenes) - 1  # the first frame has no predecessor


def test_two_thread_scan_finds_small_and_large_tags_across_the_seam() -> None:
    # the upper half ends at row 360 + 64, the lower starts at 360 - 64: a small tag in the
    # overlap, a large one across both parts (half-resolution scan), small ones elsewhere
    quads = [
        (5, _square(300, 345, 30)),
        (6, _square(700, 180, 330)),
        (7, _square(100, 40, 24)),
        (8, _square(1000, 600, 26)),
    ]
    gray = _gray(render_markers(1280, 720, quads, background=220))
    detector = FastDetector(config=FastDetectorConfig(scan_threads=2))
    try:
        found = _by_id(detector.detect(gray))
    finally:
        detector.close()
    assert sorted(found) == [5, 6, 7, 8]
    for tag_id, quad in quads:
        assert np.abs(found[tag_id] - quad).max() < 0.1


def test_blurred_tags_are_found_by_the_half_resolution_scan() -> None:
    quad = _square(400.3, 200.6, 90.0)
    image = _gray(render_markers(1280, 720, [(9, quad)], background=210))
    blurred = np.asarray(cv2.GaussianBlur(image, (0, 0), 3.0), dtype=np.uint8)
    found = _by_id(FastDetector().detect(blurred))
    assert list(found) == [9]
    assert np.abs(found[9] - quad).max() < 0.3


# ------------------------------------------------------------------ dictionaries, pose, errors


@pytest.mark.parametrize(
    ("dictionary", "tag_id"),
    [
        ("DICT_4X4_50", 49),
        ("DICT_5X5_100", 77),
        ("DICT_6X6_250", 201),
        ("DICT_7X7_1000", 999),
        ("DICT_ARUCO_ORIGINAL", 512),
        ("DICT_APRILTAG_16h5", 12),
        ("DICT_APRILTAG_36h11", 300),
    ],
)
def test_every_dictionary_size(dictionary: str, tag_id: int) -> None:
    quad = _square(211.4, 137.8, 140.0)
    image = render_markers(640, 480, [(tag_id, quad)], dictionary=dictionary, background=240)
    detector = make_detector("fast", dictionary)
    found = _by_id(detector.detect(_gray(image)))
    assert list(found) == [tag_id]
    assert np.abs(found[tag_id] - quad).max() < 0.06


def test_distance_from_detected_corners_matches_ground_truth() -> None:
    camera = CameraModel.named("HD720")
    generator = SceneGenerator(camera, seed=2, effects=Effects.realistic())
    poses = [
        MarkerPose(3, 0.2, (-0.6, 0.1, 1.5), yaw_deg=25.0),
        MarkerPose(8, 0.15, (0.2, -0.1, 3.0), pitch_deg=-15.0),
        MarkerPose(17, 0.3, (0.9, 0.2, 6.0), roll_deg=40.0),
    ]
    scene = generator.scene_from_poses(poses)
    intrinsics = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy)
    found = _by_id(FastDetector().detect(_gray(scene)))
    assert sorted(found) == [3, 8, 17]
    for marker in scene.markers:
        pose = estimate_pose(found[marker.tag_id], marker.size_m, intrinsics)
        assert pose is not None
        assert pose.distance_m == pytest.approx(marker.distance_m, rel=0.01)


@pytest.mark.parametrize("shape", [(1, 17), (17, 1), (2, 2000), (11, 11), (12, 40), (47, 47)])
def test_tiny_and_thin_images_give_no_detections(shape: tuple[int, int]) -> None:
    detector = FastDetector()
    for value in (0, 128, 255):  # twice: through the tracking path as well
        assert detector.detect(np.full(shape, value, np.uint8)) == []
        assert detector.detect(np.full(shape, value, np.uint8)) == []


def test_bad_configuration_and_input_are_refused() -> None:
    with pytest.raises(SettingsError):
        FastDetectorConfig(full_scan_period=0)
    with pytest.raises(SettingsError):
        FastDetectorConfig(scan_windows=(1, 3, 1))
    with pytest.raises(SettingsError):
        FastDetectorConfig(scan_threads=3)
    with pytest.raises(SettingsError):
        FastDetector("DICT_NOPE")
    with pytest.raises(ValueError, match="grey"):
        FastDetector().detect(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match="colour"):
        FastDetector().detect_converting(np.zeros((10, 10), np.uint8), cv2.COLOR_BGR2GRAY)


def test_a_tag_appearing_on_a_still_scene_is_reported_on_that_frame() -> None:
    """No scene cut (most of the frame is unchanged), yet the new tags are found at once."""

    def square(x0: float, y0: float, side: float) -> np.ndarray:
        return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])

    detector = FastDetector("DICT_4X4_50")
    first = render_markers(1280, 720, [(1, square(100, 100, 120))])
    later = render_markers(
        1280, 720, [(1, square(100, 100, 120)), (9, square(900, 80, 90)), (4, square(300, 420, 70))]
    )
    for image, expected in ((first, {1}), (first, {1}), (later, {1, 4, 9})):
        gray = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), dtype=np.uint8)
        assert {d.tag_id for d in detector.detect(gray)} == expected
