"""Tag pose and distance from the intrinsics and the tag's size (OpenCV's IPPE_SQUARE)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from zenoh_perception.tags.pose import (
    AMBIGUITY_MARGIN,
    AMBIGUITY_MIN_DEG,
    MEMORY_NEAR_DEG,
    Intrinsics,
    Pose,
    PoseMemory,
    chosen_by,
    estimate_pose,
    quaternion_from_rvec,
    rotation_angle_deg,
)
from zenoh_perception_bench.poses import project, tag_rotation
from zenoh_perception_bench.scene import CameraModel, MarkerPose, square_corners

VGA = Intrinsics(500.0, 500.0, 319.5, 239.5)


def _square(x0: float, y0: float, side: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def test_intrinsics_matrix_is_the_pinhole_k() -> None:
    k = Intrinsics(600.0, 610.0, 320.5, 240.25).matrix()
    np.testing.assert_array_equal(k, [[600.0, 0.0, 320.5], [0.0, 610.0, 240.25], [0, 0, 1]])
    assert k.dtype == np.float64


def test_distance_is_the_norm_of_the_translation() -> None:
    assert Pose((0.0, 0.0, 0.0), (0.6, 0.0, 0.8)).distance_m == pytest.approx(1.0)


def _reprojection_px(pose: Pose, corners: np.ndarray, size_m: float, k: Intrinsics) -> float:
    """Largest distance between ``corners`` and the tag's corners projected with ``pose``."""
    rvec, tvec = np.array(pose.rvec), np.array(pose.tvec)
    projected, _ = cv2.projectPoints(square_corners(size_m), rvec, tvec, k.matrix(), None)
    return float(np.abs(projected.reshape(4, 2) - corners).max())


def test_a_centred_fronto_parallel_tag_is_straight_ahead() -> None:
    # 100 px for 0.2 m at fx = 500: 1.0 m away, on the optical axis
    pose = estimate_pose(_square(269.5, 189.5, 100), 0.2, VGA)
    assert pose is not None
    assert pose.tvec == pytest.approx((0.0, 0.0, 1.0), abs=1e-6)
    assert pose.distance_m == pytest.approx(1.0, abs=1e-6)


def test_a_detected_fronto_parallel_tag_faces_the_camera() -> None:
    # corners as a detector reports them (a few hundredths of a pixel off): the tag's face
    # points at the camera, a half turn about x from the camera's axes (marker y up, z out)
    noise = np.array([[0.03, -0.02], [0.01, 0.02], [-0.02, 0.0], [0.0, 0.01]])
    corners = _square(269.5, 189.5, 100) + noise
    pose = estimate_pose(corners, 0.2, VGA)
    assert pose is not None
    rotation, _ = cv2.Rodrigues(np.array(pose.rvec))
    # its x axis along the image's, its face (z) toward the camera (within about 3 degrees)
    np.testing.assert_allclose(rotation[:, 0], [1.0, 0.0, 0.0], atol=0.05)
    np.testing.assert_allclose(rotation[:, 2], [0.0, 0.0, -1.0], atol=0.05)
    assert _reprojection_px(pose, corners, 0.2, VGA) < 0.25


def test_an_exactly_fronto_parallel_tag_reprojects_onto_its_corners() -> None:
    corners = _square(269.5, 189.5, 100)
    pose = estimate_pose(corners, 0.2, VGA)
    assert pose is not None
    assert _reprojection_px(pose, corners, 0.2, VGA) < 0.1


def test_distance_scales_with_the_tag_size_and_inversely_with_its_image() -> None:
    near = estimate_pose(_square(219.5, 139.5, 200), 0.2, VGA)
    big = estimate_pose(_square(269.5, 189.5, 100), 0.4, VGA)
    assert near is not None and big is not None
    assert near.distance_m == pytest.approx(0.5, rel=1e-6)
    assert big.distance_m == pytest.approx(2.0, rel=1e-6)


@pytest.mark.parametrize("size_m", [0.0, -0.2])
def test_no_pose_without_a_positive_size(size_m: float) -> None:
    assert estimate_pose(_square(269.5, 189.5, 100), size_m, VGA) is None


def test_no_pose_from_degenerate_corners() -> None:
    assert estimate_pose(np.zeros((4, 2)), 0.2, VGA) is None


_NOISE = st.floats(0.02, 0.1).flatmap(lambda size: st.sampled_from([size, -size]))


@given(
    position=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(0.6, 6.0)),
    angles=st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-180, 180)),
    size_m=st.floats(0.05, 0.5),
    noise=st.lists(_NOISE, min_size=8, max_size=8),
)
def test_the_pose_of_detected_corners_is_the_true_pose(
    position: tuple[float, float, float],
    angles: tuple[float, float, float],
    size_m: float,
    noise: list[float],
) -> None:
    """Corners as a detector reports them (the true projection, a few hundredths of a pixel
    off): the distance is the true one (within what that noise allows on a tag of a few
    pixels), and the pose projects the tag onto its corners (IPPE is exact without noise, not
    a least-squares fit: near fronto-parallel, noise moves it by more than the noise; a wrong
    rotation or sign convention would be off by the tag's size)."""
    camera = CameraModel.from_hfov(800, 600, 90.0)
    yaw, pitch, roll = angles
    truth = MarkerPose(1, size_m, position, yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
    corners = camera.project(truth.corners_3d()) + np.reshape(noise, (4, 2))
    side_px = float(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1).min())
    assume(side_px >= 15.0)  # what a detector reads at all
    intrinsics = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy)
    pose = estimate_pose(corners, size_m, intrinsics)
    assert pose is not None
    assert pose.distance_m == pytest.approx(float(np.linalg.norm(position)), rel=0.05)
    assert _reprojection_px(pose, corners, size_m, intrinsics) < 0.02 * side_px + 0.25


def _matrix_of_quaternion(q: tuple[float, float, float, float]) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.mark.parametrize(
    ("rvec", "expected"),
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        ((np.pi, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),  # half a turn about x
        ((0.0, np.pi / 2, 0.0), (0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5))),
        ((0.0, 0.0, -np.pi / 2), (0.0, 0.0, -np.sqrt(0.5), np.sqrt(0.5))),
        ((0.0, 0.0, 3 * np.pi / 2), (0.0, 0.0, -np.sqrt(0.5), np.sqrt(0.5))),  # = -pi/2
    ],
)
def test_quaternions_of_known_rotations(
    rvec: tuple[float, float, float], expected: tuple[float, float, float, float]
) -> None:
    assert quaternion_from_rvec(rvec) == pytest.approx(expected, abs=1e-12)


def test_a_tiny_rotation_keeps_its_axis() -> None:
    x, y, z, w = quaternion_from_rvec((2e-9, -4e-9, 0.0))
    assert (x, y, z) == pytest.approx((1e-9, -2e-9, 0.0), rel=1e-9)
    assert w == pytest.approx(1.0)


_ANGLE = st.floats(-10.0, 10.0, allow_nan=False)


@given(st.tuples(_ANGLE, _ANGLE, _ANGLE))
def test_the_quaternion_is_the_rotation_opencv_makes_of_the_rvec(
    rvec: tuple[float, float, float],
) -> None:
    q = quaternion_from_rvec(rvec)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
    assert q[3] >= 0.0
    rotation, _ = cv2.Rodrigues(np.array(rvec, dtype=np.float64))
    np.testing.assert_allclose(_matrix_of_quaternion(q), rotation, atol=1e-9)


def _projected(distance: float, yaw: float, pitch: float) -> np.ndarray:
    """Exact corners of a 0.2 m tag ``distance`` metres away, turned ``yaw`` and ``pitch``
    degrees from facing the camera (fx = 500), a little off the optical axis."""
    rotation = tag_rotation(yaw, pitch, 10.0)
    return project(rotation, np.array([0.1, 0.05, distance]), VGA.matrix())


@pytest.mark.parametrize(("distance", "yaw", "pitch"), [(8.0, 10.0, 5.0), (7.0, 15.0, 0.0)])
def test_a_far_tag_nearly_facing_the_camera_has_an_ambiguous_pose(
    distance: float, yaw: float, pitch: float
) -> None:
    # 12-14 px: IPPE's mirror solution puts the exact corners within a few hundredths of a
    # pixel, less than the noise of corners found on a tag that small
    pose = estimate_pose(_projected(distance, yaw, pitch), 0.2, VGA)
    assert pose is not None and pose.ambiguous
    assert pose.errors is not None and pose.errors[1] < AMBIGUITY_MARGIN / 12.0
    assert pose.other is not None
    assert rotation_angle_deg(pose.rvec, pose.other[0]) > AMBIGUITY_MIN_DEG


@pytest.mark.parametrize(("distance", "yaw", "pitch"), [(1.0, 40.0, 0.0), (2.0, 45.0, 10.0)])
def test_a_near_turned_tag_has_a_clear_pose(distance: float, yaw: float, pitch: float) -> None:
    corners = _projected(distance, yaw, pitch)
    rng = np.random.default_rng(0)
    pose = estimate_pose(corners + rng.normal(0.0, 0.05, corners.shape), 0.2, VGA)
    assert pose is not None and not pose.ambiguous
    # the mirror solution misses the corners by a pixel and more
    assert pose.errors is not None and pose.errors[1] > 1.0 > 10 * pose.errors[0]


HD720 = Intrinsics(900.0, 900.0, 639.5, 359.5)


def test_a_flipped_pose_whose_mirror_fits_twice_as_badly_is_still_marked() -> None:
    # the refined corners of a rendered 20 px tag 8 m away (bench --poses): the best IPPE
    # solution is 79 degrees off the truth, the mirror (the true pose) reprojects 1.9 times
    # as far (0.081 against 0.043 px), within what the corners' noise allows at that size
    corners = np.array(
        [[459.321, 495.782], [479.308, 501.082], [469.103, 519.226], [448.849, 514.165]]
    )
    truth = (2.32023, 0.34121, -0.29797)
    pose = estimate_pose(corners, 0.2, HD720)
    assert pose is not None and pose.errors is not None and pose.other is not None
    assert rotation_angle_deg(pose.rvec, truth) > 70.0
    assert rotation_angle_deg(pose.other[0], truth) < 10.0
    assert pose.errors[1] > 1.8 * pose.errors[0]
    assert pose.ambiguous


def _ambiguous() -> Pose:
    """The pose of a 14 px tag 7 m away nearly facing the camera: ambiguous."""
    pose = estimate_pose(_projected(7.0, 15.0, 0.0), 0.2, VGA)
    assert pose is not None and pose.ambiguous and pose.other is not None
    return pose


def _turned(rvec: tuple[float, float, float], degrees: float) -> tuple[float, float, float]:
    """``rvec`` turned ``degrees`` further about the camera's x axis."""
    turn, _ = cv2.Rodrigues(np.array([math.radians(degrees), 0.0, 0.0]))
    matrix, _ = cv2.Rodrigues(np.array(rvec))
    out, _ = cv2.Rodrigues(turn @ matrix)
    x, y, z = out.ravel().tolist()
    return (x, y, z)


def test_the_last_clear_pose_chooses_between_an_ambiguous_pose_s_solutions() -> None:
    pose = _ambiguous()
    assert pose.other is not None and pose.errors is not None
    # an anchor near the other solution picks it, still marked, its error first
    chosen = chosen_by(pose, Pose(_turned(pose.other[0], 5.0), pose.other[1]))
    assert chosen.rvec == pose.other[0] and chosen.tvec == pose.other[1]
    assert chosen.ambiguous and chosen.other == (pose.rvec, pose.tvec)
    assert chosen.errors == (pose.errors[1], pose.errors[0])
    # near the best one, or none: IPPE's best stays
    assert chosen_by(pose, Pose(_turned(pose.rvec, 5.0), pose.tvec)) is pose
    assert chosen_by(pose, None) is pose


def test_an_anchor_far_from_both_solutions_does_not_choose() -> None:
    pose = _ambiguous()
    assert pose.other is not None
    # the tag turned a long way since its clear pose: the nearer solution is too far to tell
    far = Pose(_turned(pose.other[0], MEMORY_NEAR_DEG + 5.0), pose.other[1])
    assert rotation_angle_deg(far.rvec, pose.other[0]) < rotation_angle_deg(far.rvec, pose.rvec)
    assert chosen_by(pose, far) is pose


def test_the_memory_anchors_on_clear_poses_only_and_per_tag() -> None:
    pose = _ambiguous()
    assert pose.other is not None
    memory = PoseMemory()
    assert memory.choose("a", pose) is pose  # nothing remembered yet
    clear = Pose(pose.other[0], pose.other[1])
    assert memory.choose("a", clear) is clear
    assert memory.choose("a", pose).rvec == pose.other[0]
    assert memory.choose("b", pose) is pose  # another tag's anchor is not this one's
    # a chosen pose does not become the anchor: the clear one still decides
    memory.choose("a", Pose(pose.rvec, pose.tvec, ambiguous=True, other=pose.other))
    assert memory.choose("a", pose).rvec == pose.other[0]


def test_the_memory_starts_again_past_its_capacity() -> None:
    pose = _ambiguous()
    assert pose.other is not None
    memory = PoseMemory()
    clear = Pose(pose.other[0], pose.other[1])
    for tag in range(PoseMemory.CAPACITY + 1):
        memory.choose(tag, clear)
    assert memory.choose(0, pose) is pose  # forgotten when the memory was full
    assert memory.choose(PoseMemory.CAPACITY, pose).rvec == pose.other[0]


def test_the_rotation_angle_between_rodrigues_vectors() -> None:
    assert rotation_angle_deg((0.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2)) == pytest.approx(90.0)
    assert rotation_angle_deg((0.1, 0.2, 0.3), (0.1, 0.2, 0.3)) == pytest.approx(0.0, abs=1e-3)
