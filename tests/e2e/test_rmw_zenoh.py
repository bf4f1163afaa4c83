"""End to end on an rmw_zenoh graph, with no ROS: the real ``zenoh-perception run
--ros-transport rmw_zenoh`` meets, through a Zenoh router standing in for ``rmw_zenohd``, a
test peer written from rmw_zenoh's design document alone. The peer plays an rmw_zenoh camera
node and an rmw_zenoh ``/tag`` subscriber: it declares their liveliness tokens, finds the
service's tokens (liveliness get and subscriber), and checks keys, type hashes (ROS 2's own),
attachments and their rising sequence numbers."""

from __future__ import annotations

import queue
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import zenoh

from tests.helpers import (
    REPO,
    Collector,
    Received,
    cli_command,
    json_objects,
    open_session,
    run_cli,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tests.wire.test_rmw_zenoh import ROS2_TYPE_HASHES
from zenoh_perception.wire.compressed import encode_compressed_frame
from zenoh_perception.wire.frames import RawFrameMeta, decode_raw_frame, encode_image_cdr
from zenoh_perception.wire.messages import TYPESTORE, make_typestore
from zenoh_perception.wire.records import TagCodec
from zenoh_perception.wire.rmw_zenoh import (
    PUBLISHER,
    SENSOR_DATA_QOS,
    SUBSCRIPTION,
    Attachment,
    NodeInfo,
    Token,
    decode_attachment,
    gid_of,
    parse_token,
    topic_key,
    type_hash,
)
from zenoh_perception_bench.scene import render_markers

W, H = 640, 480
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
DETECTIONS = "apriltag_msgs/msg/AprilTagDetectionArray"
TAG = "mrover/msg/StarterProjectTag"
TAG_HASH = type_hash(make_typestore("mrover"), TAG)
#: A camera of another ROS distribution: same topic and type, another definition hash.
OTHER_IMAGE_HASH = "RIHS01_" + "ab" * 32
_BLOCK = zenoh.CongestionControl.BLOCK


def _marker_frame(tag_id: int) -> np.ndarray:
    corners = np.array([[200.0, 140.0], [360.0, 140.0], [360.0, 300.0], [200.0, 300.0]])
    return render_markers(W, H, [(tag_id, corners)])


class GraphCache:
    """What a ROS 2 node on rmw_zenoh knows of the graph: the liveliness tokens alive."""

    def __init__(self, session: zenoh.Session, domain_id: int = 0) -> None:
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._subscriber = session.liveliness().declare_subscriber(
            f"@ros2_lv/{domain_id}/**", self._on_token, history=True
        )

    def _on_token(self, sample: zenoh.Sample) -> None:
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(str(sample.key_expr))
            else:
                self._alive.discard(str(sample.key_expr))

    def of_node(self, name: str) -> list[Token]:
        with self._lock:
            tokens = [parse_token(key) for key in self._alive]
        return [t for t in tokens if t.node_name == name]

    def undeclare(self) -> None:
        self._subscriber.undeclare()


@dataclass
class RosNode:
    """A ROS 2 node as rmw_zenoh declares it: its session, node token, entity tokens."""

    session: zenoh.Session
    info: NodeInfo
    declared: list[zenoh.LivelinessToken]

    def entity(
        self, entity_id: int, kind: str, topic: str, ros_type: str, hash_: str
    ) -> tuple[str, bytes]:
        """Declare an entity's token; its data key and GID."""
        token = self.info.entity_token(
            entity_id, kind, topic, ros_type, hash_=hash_, qos=SENSOR_DATA_QOS
        )
        self.declared.append(self.session.liveliness().declare_token(token))
        return topic_key(self.info.domain_id, topic, ros_type, hash_), gid_of(token)


@pytest.fixture
def node(endpoint: str) -> Iterator[RosNode]:
    """The test's ROS side: a router (standing in for rmw_zenohd) listening on ``endpoint``
    and one rmw_zenoh-style session connected to it."""
    with (
        open_session(mode="router", listen=[endpoint]),
        open_session(connect=[endpoint]) as session,
    ):
        info = NodeInfo(0, str(session.zid()), "zed_camera")
        declared = [session.liveliness().declare_token(info.node_token())]
        try:
            yield RosNode(session, info, declared)
        finally:
            for token in declared:
                token.undeclare()


def _service(endpoint: str, *extra: str) -> tuple[str, ...]:
    return (
        "run",
        "--ros-transport",
        "rmw_zenoh",
        "-e",
        endpoint,
        "-l",
        "tcp/127.0.0.1:0",
        "--stats-interval-s",
        "0",
        *extra,
    )


def _camera_answered(
    session: zenoh.Session, node: RosNode, entity_id: int, name: str, tag_id: int
) -> tuple[Any, zenoh.Publisher]:
    """A ROS publisher of ``/<name>/image`` (entity ``entity_id`` of ``node``) sends a frame of
    marker ``tag_id``; the service answers on ``/<name>/tag`` and ``/<name>/perception/
    detections``. The detection array, and the publisher (the caller undeclares it)."""
    tags = Collector(session, topic_key(0, f"/{name}/tag", TAG, TAG_HASH))
    arrays = Collector(session, topic_key(0, f"/{name}/perception/detections", DETECTIONS, "*"))
    image_key, gid = node.entity(
        entity_id, PUBLISHER, f"/{name}/image", IMAGE, ROS2_TYPE_HASHES[IMAGE]
    )
    publisher = session.declare_publisher(image_key, congestion_control=_BLOCK)
    wait_for_subscriber(publisher)
    cdr = encode_image_cdr(_marker_frame(tag_id), "bgra8", stamp_ns=1, frame_id=name)
    publisher.put(bytes(cdr), attachment=Attachment(1, time.time_ns(), gid).encode())
    assert TagCodec().decode(tags.get(timeout=30).payload).tag_id == tag_id
    array: Any = TYPESTORE.deserialize_cdr(arrays.get(timeout=30).payload, DETECTIONS)
    assert [d.id for d in array.detections] == [tag_id]
    return array, publisher


def _cameras_subscribed(graph: GraphCache) -> dict[str, Token]:
    """Wait until the service's node subscribes ``/front/image`` and ``/rear/image`` as a ROS
    node does (kind, type and type hash); the node's tokens then."""
    wait_until(
        lambda: {"/front/image", "/rear/image"} <= set(_service_tokens(graph)),
        timeout=30,
        what="the cameras' subscription tokens",
    )
    tokens = _service_tokens(graph)
    for name in ("front", "rear"):
        token = tokens[f"/{name}/image"]
        assert (token.kind, token.dds_type) == (SUBSCRIPTION, "sensor_msgs::msg::dds_::Image_")
        assert token.type_hash == ROS2_TYPE_HASHES[IMAGE]
    return tokens


def _service_tokens(graph: GraphCache) -> dict[str, Token]:
    """The service's entities by mangled topic (and its node token under "NN")."""
    return {t.topic or t.kind: t for t in graph.of_node("zenoh_perception")}


def test_the_service_is_a_ros2_node_on_an_rmw_zenoh_graph(endpoint: str, node: RosNode) -> None:
    session = node.session
    graph = GraphCache(session)
    with running_cli(*_service(endpoint)) as proc:
        wait_for_status(session)  # the status stays a plain Zenoh queryable
        wanted = {
            "NN",
            "/tag",
            "/zed/left/image",
            "/zed/left/image/compressed",
            "/perception/debug/image/compressed",
            "/perception/detections",
            "/tf",
        }
        wait_until(
            lambda: set(_service_tokens(graph)) >= wanted,
            timeout=30,
            what="the service's node, publisher and subscription tokens",
        )
        tokens = _service_tokens(graph)
        zid = tokens["NN"].session_id
        assert all(t.session_id == zid and t.namespace == "/" for t in tokens.values())
        assert all(t.enclave == "/" and t.node_id == "0" for t in tokens.values())
        assert tokens["NN"].entity_id == "0"
        tag, camera = tokens["/tag"], tokens["/zed/left/image"]
        debug = tokens["/perception/debug/image/compressed"]
        assert (tag.kind, tag.dds_type, tag.type_hash) == (
            PUBLISHER,
            "mrover::msg::dds_::StarterProjectTag_",
            TAG_HASH,
        )
        assert tag.qos == "::,10:,:,:,,"  # reliable, volatile, keep last 10
        assert (camera.kind, camera.dds_type) == (SUBSCRIPTION, "sensor_msgs::msg::dds_::Image_")
        assert camera.type_hash == ROS2_TYPE_HASHES[IMAGE]
        assert (debug.kind, debug.type_hash) == (PUBLISHER, ROS2_TYPE_HASHES[COMPRESSED])
        # every detection, the transforms and the compressed camera are ROS topics too
        detections, tf = tokens["/perception/detections"], tokens["/tf"]
        compressed = tokens["/zed/left/image/compressed"]
        assert (detections.kind, detections.dds_type, detections.type_hash) == (
            PUBLISHER,
            "apriltag_msgs::msg::dds_::AprilTagDetectionArray_",
            type_hash(TYPESTORE, DETECTIONS),
        )
        assert (tf.kind, tf.dds_type) == (PUBLISHER, "tf2_msgs::msg::dds_::TFMessage_")
        assert (compressed.kind, compressed.type_hash) == (
            SUBSCRIPTION,
            ROS2_TYPE_HASHES[COMPRESSED],
        )
        assert len({t.entity_id for t in tokens.values() if t.kind != "NN"}) == 6
        # a node starting later asks for the graph as it is (the answer may come in parts
        # while links between peers are being set up: ask until it is whole)
        got: set[str] = set()

        def whole_graph() -> bool:
            replies = session.liveliness().get("@ros2_lv/0/**", timeout=5)
            got.clear()
            got.update(str(r.ok.key_expr) for r in replies if r.ok is not None)
            return sum("/zenoh_perception" in key for key in got) == len(tokens)

        wait_until(whole_graph, timeout=30, what="every token of the service in a get")
        tag_token = next(k for k in got if "/MP/" in k and "/%tag/" in k)

        # an rmw_zenoh /tag subscriber and debug image viewer, on the exact keys ROS uses
        listener = NodeInfo(0, node.info.session_id, "tag_listener", node_id=1)
        node.declared.append(session.liveliness().declare_token(listener.node_token()))
        tags = Collector(session, topic_key(0, "/tag", TAG, TAG_HASH))
        debug_images = Collector(
            session,
            topic_key(0, "/perception/debug/image/compressed", COMPRESSED, debug.type_hash),
        )
        plain_tags = Collector(session, "tag")
        arrays = Collector(session, topic_key(0, "/perception/detections", DETECTIONS, "*"))
        # the camera node: the Jazzy Image hash, then another distribution's
        image_key, camera_gid = node.entity(
            1, PUBLISHER, "/zed/left/image", IMAGE, camera.type_hash
        )
        other_key = topic_key(0, "/zed/left/image", IMAGE, OTHER_IMAGE_HASH)
        codec = TagCodec()
        received: list[Received] = []
        for i, key in enumerate([image_key] * 4 + [other_key] * 2):
            publisher = session.declare_publisher(key, congestion_control=_BLOCK)
            wait_for_subscriber(publisher)
            image = _marker_frame(i + 1)
            cdr = bytes(encode_image_cdr(image, "bgra8", stamp_ns=1_700_000_000_000_000_000 + i))
            attachment = Attachment(i + 1, time.time_ns(), camera_gid).encode()
            publisher.put(cdr, attachment=attachment)
            sample = tags.get(timeout=30)
            assert codec.decode(sample.payload).tag_id == i + 1
            received.append(sample)
            publisher.undeclare()
        # each frame's detections, in apriltag_ros's type, with their own sequence numbers
        array_samples = [arrays.get(timeout=30) for _ in range(6)]
        messages: list[Any] = [
            TYPESTORE.deserialize_cdr(a.payload, DETECTIONS) for a in array_samples
        ]
        ids = [[d.id for d in m.detections] for m in messages]
        assert ids == [[1], [2], [3], [4], [5], [6]]
        array_seqs = [decode_attachment(a.attachment or b"").sequence_number for a in array_samples]
        assert array_seqs == [1, 2, 3, 4, 5, 6]
        # a compressed camera on its rmw_zenoh key is answered too
        compressed_key, compressed_gid = node.entity(
            2, PUBLISHER, "/zed/left/image/compressed", COMPRESSED, compressed.type_hash
        )
        publisher = session.declare_publisher(compressed_key, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        frame = decode_raw_frame(_marker_frame(9).tobytes(), RawFrameMeta(W, H).to_msgpack())
        jpeg = encode_compressed_frame(frame, "jpeg", stamp_ns=1, frame_id="zed_left")
        publisher.put(
            bytes(jpeg), attachment=Attachment(1, time.time_ns(), compressed_gid).encode()
        )
        assert codec.decode(tags.get(timeout=30).payload).tag_id == 9
        publisher.undeclare()
        attachments = [decode_attachment(s.attachment or b"") for s in received]
        assert [a.sequence_number for a in attachments] == [1, 2, 3, 4, 5, 6]
        assert {a.gid for a in attachments} == {gid_of(tag_token)}
        assert all(a.source_timestamp_ns > 1_700_000_000_000_000_000 for a in attachments)
        assert received[0].payload[:4] == b"\x00\x01\x00\x00"  # CDR little-endian header
        # the debug image is a ROS topic too, with its own publisher's attachment
        shown = debug_images.get(timeout=30)
        image_msg: Any = TYPESTORE.deserialize_cdr(shown.payload, COMPRESSED)
        assert image_msg.format.startswith("jpeg")
        assert decode_attachment(shown.attachment or b"").gid == gid_of(
            next(k for k in got if "/%perception%debug%image%compressed/" in k)
        )
        # the tag is on its rmw_zenoh key only
        assert plain_tags.drain() == []
        assert proc.poll() is None
    # leaving, the node takes its tokens with it (ros2 node list forgets it)
    wait_until(lambda: not _service_tokens(graph), timeout=30, what="the service's tokens gone")
    graph.undeclare()


def test_echo_follows_the_tag_on_its_rmw_zenoh_key(endpoint: str, node: RosNode) -> None:
    session = node.session
    with running_cli(*_service(endpoint)):
        wait_for_status(session)
        echo_args = ("--ros-transport", "rmw_zenoh", "-e", endpoint, "-l", "tcp/127.0.0.1:0")
        echo = subprocess.Popen(
            cli_command("echo", *echo_args, "--tags-only", "--json", "--count", "2"),
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        done: queue.Queue[tuple[str, str]] = queue.Queue()
        threading.Thread(target=lambda: done.put(echo.communicate()), daemon=True).start()
        try:
            key, gid = node.entity(1, PUBLISHER, "/zed/left/image", IMAGE, "RIHS01_" + "0" * 64)
            publisher = session.declare_publisher(key)
            wait_for_subscriber(publisher)
            payload = bytes(encode_image_cdr(_marker_frame(7), "bgra8"))
            seq = 0
            out, err = "", ""
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:  # until echo has what it needs
                seq += 1
                publisher.put(payload, attachment=Attachment(seq, time.time_ns(), gid).encode())
                try:
                    out, err = done.get(timeout=0.2)
                    break
                except queue.Empty:
                    continue
        finally:
            if echo.poll() is None:
                echo.kill()
            echo.wait()
        assert echo.returncode == 0, err
        assert "0/tag/mrover::msg::dds_::StarterProjectTag_/*" in err
        lines = json_objects(out)
        assert len(lines) == 2
        assert all(line["tag_id"] == 7 for line in lines)
        assert all(str(line["key"]).startswith("0/tag/mrover::msg::dds_::") for line in lines)


@pytest.mark.parametrize(
    ("flag", "value", "named"),
    [
        ("--ros-domain-id", "233", "ros_domain_id"),
        ("--ros-node-name", "zenoh-perception", "ros_node_name"),
        ("--ros-namespace", "rover", "ros_namespace"),
        ("--input-key", "zed/*/image", "input_key"),
    ],
)
def test_bad_ros_graph_settings_exit_2_naming_the_setting(
    flag: str, value: str, named: str
) -> None:
    result = run_cli("run", "--ros-transport", "rmw_zenoh", f"{flag}={value}", timeout=60)
    assert result.returncode == 2, result.stderr
    assert named in result.stderr


#: Each camera's outputs under its own name, as a ROS user lays them out.
_PER_CAMERA = (
    "--compressed-input-key",
    "",
    "--tag-key",
    "{stream}/tag",
    "--record-key",
    "cams/{stream}/perception/tags",
    "--debug-image-key",
    "{stream}/perception/debug",
    "--detections-key",
    "{stream}/perception/detections",
)


def test_several_cameras_each_answer_in_their_own_namespace(endpoint: str, node: RosNode) -> None:
    """A camera pattern ('*/image'): each camera's tag and detections under its own name
    ('/front/tag'), TF one topic whose transforms name each camera's frame."""
    session = node.session
    graph = GraphCache(session)
    flags = (
        "--input-key",
        "*/image",
        *_PER_CAMERA,
        "--tag-size-m",
        "0.2",
        "--camera-fx",
        "500",
        "--camera-fy",
        "500",
        "--camera-cx",
        "320",
        "--camera-cy",
        "240",
    )
    with running_cli(*_service(endpoint, *flags)):
        wait_for_status(session)
        tf = Collector(session, topic_key(0, "/tf", "tf2_msgs/msg/TFMessage", "*"))
        for entity_id, (name, tag_id) in enumerate((("front", 3), ("rear", 9)), start=1):
            array, _publisher = _camera_answered(session, node, entity_id, name, tag_id)
            assert array.header.frame_id == name
            transforms: Any = TYPESTORE.deserialize_cdr(
                tf.get(timeout=30).payload, "tf2_msgs/msg/TFMessage"
            )
            assert [t.header.frame_id for t in transforms.transforms] == [name]
            assert [t.child_frame_id for t in transforms.transforms] == [f"tag_{tag_id}"]
        # each camera's outputs are topics of the node under the camera's name
        wait_until(
            lambda: (
                {"/front/tag", "/rear/tag", "/front/perception/detections", "/tf"}
                <= set(_service_tokens(graph))
            ),
            timeout=30,
            what="the streams' publisher tokens",
        )
        # and the node subscribes each camera topic the pattern matched, as ROS tools list it
        _cameras_subscribed(graph)


def test_a_list_of_camera_topics_each_answer_in_their_own_namespace(
    endpoint: str, node: RosNode
) -> None:
    """Two camera topics listed ('--input-key' twice): the node subscribes each at start, as
    ROS tools list it before any frame, and each camera's tag and detections are under its
    own name ('/front/tag')."""
    session = node.session
    graph = GraphCache(session)
    flags = (
        "--input-key",
        "front/image",
        "--input-key",
        "rear/image",
        *_PER_CAMERA,
    )
    with running_cli(*_service(endpoint, *flags)):
        wait_for_status(session)
        # each listed topic's subscription token is there from the start, no frame needed
        assert "/zed/left/image" not in _cameras_subscribed(graph)
        records = Collector(session, "cams/*/perception/tags")
        for entity_id, (name, tag_id) in enumerate((("front", 3), ("rear", 9)), start=1):
            _, publisher = _camera_answered(session, node, entity_id, name, tag_id)
            assert records.get(timeout=30).key == f"cams/{name}/perception/tags"
            publisher.undeclare()
        # each camera's outputs are topics of the node under the camera's name
        wait_until(
            lambda: (
                {"/front/tag", "/rear/tag", "/front/perception/detections"}
                <= set(_service_tokens(graph))
            ),
            timeout=30,
            what="the streams' publisher tokens",
        )
        # one subscription token per listed topic: none added by the frames
        subscriptions = [t for t in graph.of_node("zenoh_perception") if t.kind == SUBSCRIPTION]
        assert sorted(t.topic for t in subscriptions) == ["/front/image", "/rear/image"]
    graph.undeclare()
