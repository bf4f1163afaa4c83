"""service/ros_outputs.py: the detections and TF outputs, encoded only while subscribed."""

from __future__ import annotations

from typing import Any

import numpy as np

from tests.helpers import open_session, pipeline_of, wait_until
from zenoh_perception.service.ros_outputs import RosOutputs
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import ENCODINGS, Frame
from zenoh_perception.wire.messages import APRILTAG_DETECTION_ARRAY_TYPE, TYPESTORE
from zenoh_perception_bench.scene import render_markers


def test_an_output_is_encoded_only_while_a_subscriber_matches() -> None:
    settings = Settings()
    square = np.array([[60.0, 80.0], [160.0, 80.0], [160.0, 180.0], [60.0, 180.0]])
    image = render_markers(640, 480, [(3, square)])
    analysis = pipeline_of(settings).process(Frame(image, ENCODINGS["bgra8"], None, "cam", None))
    assert [t.tag_id for t in analysis.tags] == [3]
    with open_session() as session:
        outputs = RosOutputs(settings.outputs, settings.detection.dictionary)
        transport = RosTransport(session, settings.ros, settings.topic_keys())
        publishers = outputs.declare(transport)
        try:
            encoded, failed = outputs.encode(analysis, stamp_ns=1, frame_id="cam")
            assert (encoded, failed) == ([], [])  # nobody subscribes
            subscriber = session.declare_subscriber(
                settings.outputs.detections_key, lambda _s: None
            )
            detections = next(p for p in publishers if p.key == settings.outputs.detections_key)
            wait_until(lambda: detections.matched, timeout=10.0, what="the subscriber matched")
            encoded, failed = outputs.encode(analysis, stamp_ns=1, frame_id="cam")
            assert failed == []
            assert [e.name for e in encoded] == ["detections"]  # TF has no subscriber
            array: Any = TYPESTORE.deserialize_cdr(
                encoded[0].payload, APRILTAG_DETECTION_ARRAY_TYPE
            )
            assert [d.id for d in array.detections] == [3]
            subscriber.undeclare()
            wait_until(lambda: not detections.matched, timeout=10.0, what="no subscriber left")
            assert outputs.encode(analysis, stamp_ns=1, frame_id="cam") == ([], [])
        finally:
            for publisher in publishers:
                publisher.undeclare()
