"""tools/frame_path.py: what it counts between Zenoh's callback and the tag put."""

from __future__ import annotations

from tools.frame_path import main


def test_the_path_runs_from_the_callback_to_the_tag_through_the_detector() -> None:
    path = main(frames=2)
    assert path["frames"] == 2
    calls = path["calls_of_the_last_frame"]
    # the callback thread's first call, and the worker's last before the put
    assert calls[0] == "service.node.PerceptionService._on_input"
    assert calls[-1] == "service.ros_transport.TopicPublisher.put"
    assert "detect.opencv.read_markers" in calls
    # the objects around OpenCV's read, outermost first
    assert path["wrapper_classes"][-2:] == ["GuardedDetector", "OpenCvDetector"]
    assert 0 < path["package_calls"] <= path["python_calls"]
    assert path["modules"] <= len(path["modules_seen"]) and "service.stream" in path["modules_seen"]
