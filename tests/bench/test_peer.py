"""``bench --peer ros2``: the message when the ros2 extra is missing, the flags, and, where
ROS 2's Python packages are importable, a two-frame run through every path."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from tests.helpers import run_cli
from zenoh_perception.cli import main as cli
from zenoh_perception_bench import peer

#: The Python with the ros2 extra: this one, or the one named by ZP_ROS_PYTHON.
ROS_PYTHON = os.environ.get("ZP_ROS_PYTHON", sys.executable)
HAS_ROS2 = peer.ros2_available(ROS_PYTHON)


def test_peer_flags_parse() -> None:
    args = cli.build_parser().parse_args(["bench", "--peer", "ros2", "--ros-python", "/x/py"])
    assert args.peer == "ros2"
    assert args.ros_python == "/x/py"
    assert cli.build_parser().parse_args(["bench"]).peer is None


def test_unknown_peer_is_refused() -> None:
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args(["bench", "--peer", "dds"])
    assert exc.value.code == 2


def test_missing_ros2_exits_2_with_the_install_line() -> None:
    # a Python that does not exist stands for one without the extra, wherever the suite runs
    done = run_cli("bench", "--peer", "ros2", "--ros-python", "/nonexistent/python")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "pip install -e '.[ros2]'" in lines[0]


def test_ros2_available_is_false_for_a_python_without_rclpy() -> None:
    assert not peer.ros2_available("/nonexistent/python")


def test_summary_counts_lost_frames_and_excess_over_bare() -> None:
    run = peer.PeerRun(
        {
            peer.BARE: [4.0, 4.0],
            "floor": [1.0, 1.0],
            "ros2 best_effort": [None, 10.0],
        },
        frames=2,
    )
    rows = {row["path"]: row for row in peer.summary(run)}
    assert rows["ros2 best_effort"]["answered"] == 1
    assert rows["ros2 best_effort"]["over_bare_ms"] == pytest.approx(6.0)
    assert rows["ros2 best_effort"]["ratio_to_bare"] == pytest.approx(2.5)
    assert rows["ros2 best_effort"]["over_floor_ms"] == pytest.approx(9.0)
    assert "1/2" in peer.report(run)


@pytest.mark.skipif(not HAS_ROS2, reason="ROS 2 Jazzy's Python packages are not importable")
@pytest.mark.timeout(300)
def test_two_frames_through_every_path() -> None:
    images = peer.peer_frames(2, seed=7)
    run = peer.run_peer(images, ROS_PYTHON, None)
    assert set(run.times) == {peer.BARE, "floor", peer.SERVICE, "ros2 reliable", "ros2 best_effort"}
    for name in (peer.BARE, "floor", peer.SERVICE, "ros2 reliable"):  # best effort may lose
        assert all(t is not None for t in run.times[name]), name
        assert len(run.times[name]) == 2
    assert np.isfinite(peer.summary(run)[0]["median_ms"])
