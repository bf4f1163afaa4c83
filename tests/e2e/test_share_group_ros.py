"""ROS cameras shared by a group: real ``zenoh-perception run`` processes learn the cameras
from the tokens ROS already declares, and split them as they split this project's cameras.

- Behind zenoh-bridge-ros2dds: the bridge announces each publisher route with an ``MP``
  token, built here by :func:`~zenoh_perception.wire.bridge_liveliness.publisher_token` as
  eclipse-zenoh/zenoh-plugin-ros2dds writes it (``zenoh-plugin-ros2dds/src/liveliness_mgt.rs``,
  tag 1.10.0, commit 63e9d614cdf0f64c208d79a058c90db96f7b50ce), and publishes
  sensor_msgs/Image CDR on the route's plain key.
- On an rmw_zenoh graph (``--ros-transport rmw_zenoh``): each camera publisher declares its
  ``MP`` token, built by :meth:`~zenoh_perception.wire.rmw_zenoh.NodeInfo.entity_token` as
  ros2/rmw_zenoh writes it (``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``, commit
  3411fdec149fe0c932f24d4d79ef908eb81d7482; ``docs/design.md``), and publishes on the topic's
  data key with rmw_zenoh's attachment.
"""

from __future__ import annotations

import queue
import time
from collections import Counter
from contextlib import ExitStack

import numpy as np
import zenoh

from tests.e2e.test_share_group import CAMERAS, _instance, _split, router
from tests.helpers import Collector, running_cli
from tests.wire.test_rmw_zenoh import ROS2_TYPE_HASHES
from zenoh_perception.wire.bridge_liveliness import BridgeQos, publisher_token
from zenoh_perception.wire.frames import encode_image_cdr
from zenoh_perception.wire.records import decode_record
from zenoh_perception.wire.rmw_zenoh import PUBLISHER, SENSOR_DATA_QOS, Attachment, NodeInfo, gid_of
from zenoh_perception_bench.scene import render_markers

__all__ = ["router"]  # the fixture, used by name

IMAGE = "sensor_msgs/msg/Image"
W, H = 320, 240


def _frame() -> np.ndarray:
    corners = np.array([[100.0, 70.0], [180.0, 70.0], [180.0, 150.0], [100.0, 150.0]])
    return render_markers(W, H, [(3, corners)])


class RosCameras:
    """Four ROS camera publishers; ``put`` sends frame ``seq`` (its stamp) of one."""

    def __init__(self, session: zenoh.Session, keys: dict[str, str]) -> None:
        self._frame = _frame()
        self._publishers = {
            name: session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            for name, key in keys.items()
        }
        self.attachments: dict[str, bytes] = {}

    def put(self, name: str, seq: int) -> None:
        cdr = encode_image_cdr(self._frame, "bgra8", stamp_ns=seq + 1, frame_id=name)
        attachment = self.attachments.get(name)
        self._publishers[name].put(bytes(cdr), attachment=attachment)

    def close(self) -> None:
        for publisher in self._publishers.values():
            publisher.undeclare()


def _answer_each_once(cameras: RosCameras, records: Collector, seq: int) -> Counter[str]:
    """Put frame ``seq`` of every camera, each answered before the next; the records of each
    camera's frame, counted until 2 s pass without one."""
    answered: Counter[str] = Counter()
    for name in CAMERAS:
        cameras.put(name, seq)
        deadline = time.monotonic() + 20.0
        while name not in answered and time.monotonic() < deadline:
            try:
                record = decode_record(records.get(timeout=1.0).payload)
            except queue.Empty:
                continue
            if record["stamp_ns"] == seq + 1:
                answered[record["frame_id"]] += 1
    while True:
        try:
            record = decode_record(records.get(timeout=2.0).payload)
        except queue.Empty:
            return answered
        if record["stamp_ns"] == seq + 1:
            answered[record["frame_id"]] += 1


def test_cameras_behind_a_bridge_are_split_by_their_route_tokens(
    router: tuple[str, zenoh.Session],
) -> None:
    endpoint, session = router
    keys = {name: f"cams/{name}/image" for name in CAMERAS}
    bridge = "1f2e3d4c5b6a79881f2e3d4c5b6a7988"
    routes = [
        session.liveliness().declare_token(publisher_token(bridge, key, IMAGE, BridgeQos()))
        for key in keys.values()
    ]
    cameras = RosCameras(session, keys)
    records = Collector(session, "cams/*/perception/tags")
    with ExitStack() as stack:
        stack.callback(cameras.close)
        for token in routes:
            stack.callback(token.undeclare)
        for _ in range(2):
            stack.enter_context(running_cli(*_instance(endpoint)))
        split = _split(session, 2)
        assert set().union(*split.values()) == set(keys.values())
        for seq in range(2):
            assert _answer_each_once(cameras, records, seq) == dict.fromkeys(CAMERAS, 1)


def test_rmw_zenoh_cameras_are_split_by_their_publisher_tokens(
    router: tuple[str, zenoh.Session],
) -> None:
    endpoint, session = router
    node = NodeInfo(0, str(session.zid()), "zed_camera")
    tokens = [session.liveliness().declare_token(node.node_token())]
    keys: dict[str, str] = {}
    gids: dict[str, bytes] = {}
    for entity, name in enumerate(CAMERAS, start=1):
        announced = node.entity_token(
            entity,
            PUBLISHER,
            f"/cams/{name}/image",
            IMAGE,
            hash_=ROS2_TYPE_HASHES[IMAGE],
            qos=SENSOR_DATA_QOS,
        )
        tokens.append(session.liveliness().declare_token(announced))
        keys[name] = f"0/cams/{name}/image/sensor_msgs::msg::dds_::Image_/{ROS2_TYPE_HASHES[IMAGE]}"
        gids[name] = gid_of(announced)
    cameras = RosCameras(session, keys)
    cameras.attachments = {
        name: Attachment(1, time.time_ns(), gid).encode() for name, gid in gids.items()
    }
    records = Collector(session, "cams/*/perception/tags")
    flags = [*_instance(endpoint), "--ros-transport", "rmw_zenoh", "-l", "tcp/127.0.0.1:0"]
    with ExitStack() as stack:
        stack.callback(cameras.close)
        for token in tokens:
            stack.callback(token.undeclare)
        for _ in range(2):
            stack.enter_context(running_cli(*flags))
        split = _split(session, 2)
        assert set().union(*split.values()) == set(keys.values())
        for seq in range(2):
            assert _answer_each_once(cameras, records, seq) == dict.fromkeys(CAMERAS, 1)
