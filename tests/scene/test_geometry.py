"""Camera models and marker poses: projection, sizes, distances and the pose convention."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.scene.cases import facing
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception_bench.scene import (
    CameraModel,
    DistractorPose,
    MarkerPose,
    SceneError,
    SceneGenerator,
    square_corners,
)


def test_camera_from_hfov_and_named_resolutions() -> None:
    cam = CameraModel.from_hfov(1920, 1080, 90.0)
    assert cam.fx == pytest.approx(960.0)
    assert (cam.cx, cam.cy) == (959.5, 539.5)
    expected = np.array([[960.0, 0.0, 959.5], [0.0, 960.0, 539.5], [0.0, 0.0, 1.0]])
    assert np.allclose(cam.matrix, expected)
    assert np.allclose(cam.project([[0.0, 0.0, 3.0]]), [[959.5, 539.5]])
    for name, size in RESOLUTIONS.items():
        assert CameraModel.named(name).size == size
    with pytest.raises(SceneError):
        CameraModel.named("8K")
    with pytest.raises(SceneError):
        CameraModel.from_hfov(640, 480, 0.0)
    with pytest.raises(SceneError):
        cam.project([[0.0, 0.0, -1.0]])


@pytest.mark.parametrize(("size_m", "z"), [(0.2, 1.0), (0.15, 3.7), (0.3, 8.0)])
def test_fronto_parallel_size_and_distance(size_m: float, z: float) -> None:
    cam = CameraModel.named("HD720")
    scene = SceneGenerator(cam, seed=1).scene_from_poses([facing(4, size_m, 0.1, -0.05, z)])
    (truth,) = scene.markers
    assert truth.side_px == pytest.approx(cam.fx * size_m / z, rel=1e-9)
    assert truth.distance_m == pytest.approx(math.sqrt(0.1**2 + 0.05**2 + z**2))
    assert np.allclose(truth.centre, cam.project([[0.1, -0.05, z]])[0])
    # upright and facing: corners in image order TL, TR, BR, BL
    tl, tr, br, bl = truth.corners
    assert tl[0] < tr[0] and tl[1] < bl[1] and br[0] > bl[0] and br[1] > tr[1]


def test_positive_roll_turns_the_marker_clockwise_in_the_image() -> None:
    cam = CameraModel.named("VGA")
    pose = MarkerPose(1, 0.2, (0.0, 0.0, 2.0), roll_deg=90.0)
    corners = cam.project(pose.corners_3d())
    # the marker's top-left corner is now at the image top-right
    assert corners[0, 0] > cam.cx and corners[0, 1] < cam.cy


@settings(max_examples=40, deadline=None)
@given(
    position=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(0.6, 6.0)),
    angles=st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-180, 180)),
)
def test_truth_pose_reprojects_to_truth_corners(
    position: tuple[float, float, float], angles: tuple[float, float, float]
) -> None:
    cam = CameraModel.from_hfov(800, 600, 90.0)
    gen = SceneGenerator(cam, seed=0)
    yaw, pitch, roll = angles
    pose = MarkerPose(9, 0.2, position, yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
    scene = gen.scene_from_poses([pose])
    if not scene.markers:  # entirely outside the image
        return
    (truth,) = scene.markers
    projected, _ = cv2.projectPoints(square_corners(0.2), truth.rvec, truth.tvec, cam.matrix, None)
    assert np.allclose(projected.reshape(4, 2), truth.corners, atol=1e-6)
    # same convention as cv2.solvePnP (SQPnP here: IPPE_SQUARE gives NaN on some exactly
    # fronto-parallel noise-free quads in OpenCV 5.0)
    ok, rvec, tvec = cv2.solvePnP(
        square_corners(0.2), truth.corners, cam.matrix, None, flags=cv2.SOLVEPNP_SQPNP
    )
    # (solver precision is about 1e-6: a wrong convention would be off by order 1)
    assert ok and np.allclose(tvec.reshape(3), truth.tvec, atol=1e-5)
    rotation, _ = cv2.Rodrigues(rvec)
    truth_rotation, _ = cv2.Rodrigues(truth.rvec)
    assert np.allclose(rotation, truth_rotation, atol=1e-5)
    # the centre is where the diagonals cross
    a, c = truth.corners[0], truth.corners[2]
    b, d = truth.corners[1], truth.corners[3]
    t = np.linalg.solve(np.stack([c - a, b - d], axis=1), b - a)[0]
    assert np.allclose(a + t * (c - a), truth.centre, atol=1e-6)
    assert truth.distance_m == pytest.approx(float(np.linalg.norm(truth.tvec)))


def test_marker_pose_validation() -> None:
    with pytest.raises(SceneError):
        MarkerPose(1, 0.0, (0.0, 0.0, 1.0))
    with pytest.raises(SceneError):
        MarkerPose(1, 0.1, (0.0, 0.0, 1.0), yaw_deg=10.0, rvec=(0.0, 0.0, 0.0))
    with pytest.raises(SceneError):
        DistractorPose("blob", 0.1, (0.0, 0.0, 1.0))  # hides a code: needs mimic_id
    with pytest.raises(SceneError):
        DistractorPose("sticker", 0.1, (0.0, 0.0, 1.0))
