"""End to end: every detection (apriltag_msgs/AprilTagDetectionArray) and the tags' transforms
(tf2_msgs/TFMessage) from the real ``zenoh-perception run``, read back with rosbags."""

from __future__ import annotations

import queue
import time
from typing import Any

import cv2
import numpy as np
import pytest
import zenoh

from tests.helpers import (
    WAIT_S,
    Collector,
    loopback_endpoint,
    open_session,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
)
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.messages import (
    APRILTAG_DETECTION_ARRAY_TYPE,
    TF_MESSAGE_TYPE,
    TYPESTORE,
)
from zenoh_perception.wire.records import decode_record
from zenoh_perception_bench.scene import render_markers

W, H = 640, 480
_BLOCK = zenoh.CongestionControl.BLOCK
STAMP = 1_700_000_000_123_456_789
#: 0.2 m tags seen by a 500 px focal length: a 200 px tag is 0.5 m away
POSE_FLAGS = (
    "--camera-fx", "500", "--camera-fy", "500", "--camera-cx", "320", "--camera-cy", "240",
    "--tag-size-m", "0.2",
)  # fmt: skip


def _square(x0: float, y0: float, side: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


MARKERS = [(3, _square(60, 80, 100)), (8, _square(330, 150, 200))]


def _decode(payload: bytes, typename: str) -> Any:
    return TYPESTORE.deserialize_cdr(payload, typename)


def test_run_publishes_every_detection_and_each_tags_transform(endpoint: str) -> None:
    with (
        running_cli(
            "run", "-l", endpoint, "--no-multicast-scouting", "--tf-prefix", "fiducial_",
            *POSE_FLAGS,
        ) as proc,
        open_session(connect=[endpoint]) as camera,
    ):  # fmt: skip
        wait_for_status(camera)
        detections = Collector(camera, "perception/detections")
        transforms = Collector(camera, "tf")
        records = Collector(camera, "perception/tags")
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        meta = RawFrameMeta(W, H, stamp_ns=STAMP, frame_id="zed_left_optical")
        publisher.put(render_markers(W, H, MARKERS).tobytes(), attachment=meta.to_msgpack())

        array = _decode(detections.get().payload, APRILTAG_DETECTION_ARRAY_TYPE)
        assert (array.header.stamp.sec, array.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
        assert array.header.frame_id == "zed_left_optical"
        by_id = {d.id: d for d in array.detections}
        assert sorted(by_id) == [3, 8]
        for tag_id, corners in MARKERS:
            found = by_id[tag_id]
            assert found.family == "DICT_4X4_50"
            got = np.array([(c.x, c.y) for c in found.corners])
            np.testing.assert_allclose(got, corners, atol=1.5)
            centre = corners.mean(axis=0)
            assert (found.centre.x, found.centre.y) == pytest.approx(tuple(centre), abs=1.5)
            # the homography takes apriltag's square centre to the tag's centre
            u, v, w = np.array(found.homography).reshape(3, 3) @ np.array([0.0, 0.0, 1.0])
            assert (u / w, v / w) == pytest.approx(tuple(centre), abs=1.5)

        tf = _decode(transforms.get().payload, TF_MESSAGE_TYPE)
        by_child = {t.child_frame_id: t for t in tf.transforms}
        assert sorted(by_child) == ["fiducial_3", "fiducial_8"]
        near = by_child["fiducial_8"]
        assert near.header.frame_id == "zed_left_optical"
        assert (near.header.stamp.sec, near.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
        t, r = near.transform.translation, near.transform.rotation
        # centre (430, 250) px at 0.5 m: 0.11 m right, 0.01 m down
        assert (t.x, t.y, t.z) == pytest.approx((0.11, 0.01, 0.5), abs=0.005)
        # facing the camera: half a turn about x (the tag's y up, its z towards the camera)
        assert (abs(r.x), r.y, r.z, r.w) == pytest.approx((1.0, 0.0, 0.0, 0.0), abs=0.02)

        record = decode_record(records.get().payload)
        pose = {tag["tag_id"]: tag["pose"] for tag in record["tags"]}[8]
        assert pose["quaternion"] == [r.x, r.y, r.z, r.w]
        assert pose["tvec"] == [t.x, t.y, t.z]

        # a frame without tags: an empty array, and no transform at all
        empty = RawFrameMeta(W, H, stamp_ns=STAMP + 1, frame_id="zed_left_optical")
        publisher.put(render_markers(W, H, []).tobytes(), attachment=empty.to_msgpack())
        assert list(_decode(detections.get().payload, APRILTAG_DETECTION_ARRAY_TYPE)
                    .detections) == []  # fmt: skip
        decode_record(records.get().payload)  # the frame is fully answered
        # the record is published before the ROS outputs: wait for the next frame's array too
        publisher.put(render_markers(W, H, MARKERS).tobytes(), attachment=meta.to_msgpack())
        assert len(_decode(detections.get().payload, APRILTAG_DETECTION_ARRAY_TYPE)
                   .detections) == 2  # fmt: skip
        second = _decode(transforms.get().payload, TF_MESSAGE_TYPE)
        assert len(second.transforms) == 2  # the next TF is this frame's: none came between
        assert transforms.drain() == []
        assert proc.poll() is None


def _answered_without_tf(publisher: zenoh.Publisher, everything: Collector, seq: int) -> bool:
    """Put frame ``seq``; True once its detections array came (no transform before it), False
    when nothing more came for a while."""
    meta = RawFrameMeta(W, H, seq=seq, frame_id="cam")
    publisher.put(render_markers(W, H, MARKERS).tobytes(), attachment=meta.to_msgpack())
    while True:
        try:
            sample = everything.get(timeout=5.0)
        except queue.Empty:
            return False
        assert sample.key != "tf"
        if sample.key == "perception/detections":
            return True


@pytest.mark.parametrize(
    "flags",
    [(), ("--tf-key", "", *POSE_FLAGS)],
    ids=["no pose", "tf off"],
)
def test_no_transform_without_a_pose_or_with_tf_off(endpoint: str, flags: tuple[str, ...]) -> None:
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting", *flags) as proc,
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        everything = Collector(camera, "**")
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        # The service may learn of the "**" subscriber after a first frame's outputs: frames
        # until one frame's array comes (each answered in full, none with a transform)
        deadline = time.monotonic() + WAIT_S
        warm = 0
        while not _answered_without_tf(publisher, everything, warm := warm + 1):
            assert time.monotonic() < deadline, "no detections array from the service"
        for seq in (warm + 1, warm + 2):
            meta = RawFrameMeta(W, H, seq=seq, frame_id="cam")
            publisher.put(render_markers(W, H, MARKERS).tobytes(), attachment=meta.to_msgpack())
            # one frame at a time, each fully answered (its array is its last output)
            while True:
                sample = everything.get()
                if sample.key == "perception/detections":
                    array = _decode(sample.payload, APRILTAG_DETECTION_ARRAY_TYPE)
                    assert sorted(d.id for d in array.detections) == [3, 8]
                    break
                assert sample.key != "tf"
        # the worker publishes a frame's outputs in turn: the first frame's transforms, had
        # there been any, would have come before the second frame's outputs
        assert "tf" not in {sample.key for sample in everything.drain()}
        assert proc.poll() is None


def _debug_image(flags: tuple[str, ...], endpoint: str) -> np.ndarray:
    """The first debug image the real service draws for a frame of MARKERS."""
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting", *flags),
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        debug = Collector(camera, "perception/debug/image/compressed")
        records = Collector(camera, "perception/tags")
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        meta = RawFrameMeta(W, H, frame_id="cam")
        for _ in range(100):  # until the service has seen the debug subscriber
            publisher.put(render_markers(W, H, MARKERS).tobytes(), attachment=meta.to_msgpack())
            decode_record(records.get().payload)
            sample = debug.drain()
            if sample:
                msg: Any = TYPESTORE.deserialize_cdr(
                    sample[0].payload, "sensor_msgs/msg/CompressedImage"
                )
                image = cv2.imdecode(np.asarray(msg.data), cv2.IMREAD_COLOR)
                assert image is not None
                return image
        raise AssertionError("no debug image")


def _reddish(image: np.ndarray, x: int, y: int) -> bool:
    patch = image[y - 2 : y + 3, x - 2 : x + 3].reshape(-1, 3).astype(int)
    return bool(np.any((patch[:, 2] > 150) & (patch[:, 1] < 110) & (patch[:, 0] < 110)))


def test_the_debug_image_draws_the_axes_of_posed_tags(endpoint: str) -> None:
    # tag 8 (centre 430, 250) at 0.5 m: its x axis, 0.1 m long, runs 100 px to the right
    posed = _debug_image(POSE_FLAGS, endpoint)
    assert _reddish(posed, 470, 250) and _reddish(posed, 500, 250)
    plain = _debug_image((), loopback_endpoint())
    assert not _reddish(plain, 470, 250) and not _reddish(plain, 500, 250)
