"""The peer users would otherwise run: a ROS 2 node written the way ros2_aruco is, and a
lockstep ROS 2 camera for it (``bench --peer ros2``, :mod:`~zenoh_perception_bench.peer`).

Run only as a subprocess, in a Python where the ``ros2`` extra is installed (rclpy, the
message packages, rmw_fastrtps_cpp)::

    python -m zenoh_perception_bench.ros2_peer node --qos reliable --input T --output T
    python -m zenoh_perception_bench.ros2_peer camera --frames F.npy --route QOS:IN:OUT ...

``node``: ``sensor_msgs/Image`` (bgra8) in; the data viewed in place as a numpy array (what
cv_bridge's ``imgmsg_to_cv2`` gives), grey, OpenCV's default ``ArucoDetector``; a
``geometry_msgs/PoseArray`` out (one pose per marker, its centre pixel in x, y; the image's
header, so the camera can tell which frame it answers).

``camera``: reads lines ``ROUTE INDEX`` on stdin; for each builds the ``Image`` of frame INDEX
(untimed, as the bench's Zenoh camera loads its buffer before the clock starts), publishes it
on the route's input topic and waits for the answer on its output topic; writes back one line,
the milliseconds from ``publish`` to the answer, or ``lost`` when none came within
``--lost-after-s``. It first writes ``ready`` once every route has answered a warm-up frame.
Every QoS is the node's: ``reliable`` (depth 10) or ``best_effort`` (``qos_profile_sensor_data``,
what ros2_aruco subscribes images with); the answers go back reliable (depth 10).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import Any, Final

import cv2
import numpy as np
import rclpy
from geometry_msgs.msg import Pose, PoseArray
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import Image

#: The image QoS per name.
QOS: Final[dict[str, QoSProfile]] = {
    "reliable": QoSProfile(depth=10),
    "best_effort": qos_profile_sensor_data,
}
ANSWER_QOS: Final = QoSProfile(depth=10)
#: frame_id of the warm-up frames.
WARMUP: Final = "warmup"
WARMUP_TRIES: Final = 10


def _detector(dictionary: str) -> Any:
    family = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    return cv2.aruco.ArucoDetector(family, cv2.aruco.DetectorParameters())


def run_node(args: argparse.Namespace) -> int:
    """The ros2_aruco-style detector node, until SIGINT/SIGTERM."""
    rclpy.init()
    node = Node("aruco_bench_node")
    detector = _detector(args.dictionary)
    answers = node.create_publisher(PoseArray, args.output, ANSWER_QOS)

    def on_image(msg: Image) -> None:
        # cv_bridge's imgmsg_to_cv2 without cv_bridge: a view of the message's data
        image = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 4)
        grey = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
        corners, _ids, _rejected = detector.detectMarkers(grey)
        out = PoseArray()
        out.header = msg.header
        for quad in corners:
            centre = quad.reshape(4, 2).mean(axis=0)
            pose = Pose()
            pose.position.x = float(centre[0])
            pose.position.y = float(centre[1])
            out.poses.append(pose)
        answers.publish(out)

    node.create_subscription(Image, args.input, on_image, QOS[args.qos])
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


class _Route:
    """One node's image publisher and answer subscription, on the camera's node."""

    def __init__(self, node: Node, spec: str) -> None:
        self.qos, image_topic, answer_topic = spec.split(":")
        self.publisher = node.create_publisher(Image, image_topic, QOS[self.qos])
        self.answers: dict[str, float] = {}
        self.arrived = threading.Condition()
        self.subscription = node.create_subscription(
            PoseArray, answer_topic, self._on_answer, ANSWER_QOS
        )

    def _on_answer(self, msg: PoseArray) -> None:
        now = time.perf_counter()
        with self.arrived:
            self.answers[msg.header.frame_id] = now
            self.arrived.notify_all()

    def warm_up(self, blank: Image, deadline: float) -> bool:
        """Until the node is discovered both ways and has answered a blank frame (a route
        that loses frames gets a few tries only: its losses are what the bench counts)."""
        while not (self.publisher.get_subscription_count() and self._subscription_matched()):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        tries = 0
        while self.send(blank, 1.0) is None:
            tries += 1
            if time.monotonic() > deadline or (self.qos != "reliable" and tries >= WARMUP_TRIES):
                return self.qos != "reliable"
        return True

    def _subscription_matched(self) -> bool:
        return bool(self.subscription.get_publisher_count())

    def send(self, msg: Image, timeout: float) -> float | None:
        """Publish; perf_counter() seconds from publish to its answer (None: lost)."""
        key = msg.header.frame_id
        with self.arrived:
            self.answers.pop(key, None)
        start = time.perf_counter()
        self.publisher.publish(msg)
        deadline = start + timeout
        with self.arrived:
            while key not in self.answers:
                left = deadline - time.perf_counter()
                if left <= 0:
                    return None
                self.arrived.wait(left)
            return self.answers.pop(key) - start


def _image(frame: np.ndarray[Any, Any], frame_id: str) -> Image:
    msg = Image()
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(frame.shape[0]), int(frame.shape[1])
    msg.encoding = "bgra8"
    msg.step = msg.width * 4
    msg.data = np.ascontiguousarray(frame).tobytes()
    return msg


def run_camera(args: argparse.Namespace) -> int:
    """The lockstep camera driven over stdin/stdout (see the module doc)."""
    frames = np.load(args.frames, mmap_mode="r")
    rclpy.init()
    node = Node("aruco_bench_camera")
    routes = {route.qos: route for route in (_Route(node, spec) for spec in args.route)}
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        blank = _image(np.zeros_like(frames[0]), WARMUP)
        deadline = time.monotonic() + args.startup_s
        for route in routes.values():
            if not route.warm_up(blank, deadline):
                print(f"error: no answer on the {route.qos} route", flush=True)
                return 1
        print("ready", flush=True)
        for line in sys.stdin:
            name, index = line.split()
            msg = _image(frames[int(index)], index)
            took = routes[name].send(msg, args.lost_after_s)
            print("lost" if took is None else f"{took * 1e3:.4f}", flush=True)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m zenoh_perception_bench.ros2_peer")
    sub = parser.add_subparsers(dest="role", required=True)
    node = sub.add_parser("node")
    node.add_argument("--qos", choices=sorted(QOS), required=True)
    node.add_argument("--input", required=True)
    node.add_argument("--output", required=True)
    node.add_argument("--dictionary", default="DICT_4X4_50")
    camera = sub.add_parser("camera")
    camera.add_argument("--frames", required=True, help=".npy of BGRA frames")
    camera.add_argument("--route", action="append", required=True, metavar="QOS:IN:OUT")
    camera.add_argument("--lost-after-s", type=float, default=0.5)
    camera.add_argument("--startup-s", type=float, default=90.0)
    args = parser.parse_args(argv)
    return run_node(args) if args.role == "node" else run_camera(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
