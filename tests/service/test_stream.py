"""service/stream.py: publishers shared by streams whose keys are alike, undeclared with the
last of them."""

from __future__ import annotations

import pytest
import zenoh

from tests.helpers import STREAMS, open_session, wait_until
from zenoh_perception.service.outputs import PublisherPool
from zenoh_perception.service.ros_transport import RosTransport


def test_a_key_without_stream_is_one_publisher_for_every_stream(endpoint: str) -> None:
    with open_session(listen=[endpoint]) as session, open_session(connect=[endpoint]) as peer:
        publishers = PublisherPool(
            session, RosTransport(session, STREAMS.ros, STREAMS.topic_keys())
        )
        front_tf = publishers.ros("tf", "front", express=True)
        rear_tf = publishers.ros("tf", "rear", express=True)
        assert front_tf is rear_tf and front_tf.key == "tf"  # one TF topic
        front_tag = publishers.ros("tag", "front", express=True)
        rear_tag = publishers.ros("tag", "rear", express=True)
        assert (front_tag.key, rear_tag.key) == ("cams/front/tag", "cams/rear/tag")
        subscriber = peer.declare_subscriber("tf", lambda _s: None)
        wait_until(lambda: front_tf.matched, timeout=10, what="TF matched")
        publishers.release(front_tf)  # the rear stream still publishes TF
        front_tf.put(b"still declared")
        publishers.release(rear_tf)  # the last: undeclared
        with pytest.raises(zenoh.ZError):
            front_tf.put(b"undeclared")
        for publisher in (front_tag, rear_tag):
            publishers.release(publisher)
        subscriber.undeclare()
