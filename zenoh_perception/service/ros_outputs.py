"""The service's ROS 2 outputs beside ``tag``: every detection (AprilTagDetectionArray) and the
tags' transforms (TFMessage), each an entry of the topic table
(:data:`~zenoh_perception.wire.ros_topics.ROS_TOPICS`) declared through the ROS transport
(plain key or rmw_zenoh), and only when its key setting is set. A frame's payload is encoded
only for the outputs a subscriber matches at the time (a CDR encoding costs more than the rest
of the frame's publications together)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

from zenoh_perception.errors import ProcessingError
from zenoh_perception.pipeline import Analysis
from zenoh_perception.service.ros_transport import TopicPublisher
from zenoh_perception.settings.sections import Outputs
from zenoh_perception.wire.detections import DETECTIONS_TOPIC, encode_detections
from zenoh_perception.wire.tf import TF_TOPIC, encode_tf

#: The outputs, in the order they are published on each frame; each is counted under its role
#: (publish and processing errors).
ROS_OUTPUTS: Final = (DETECTIONS_TOPIC, TF_TOPIC)

_ENCODE_ERRORS: Final = (struct.error, ValueError, OverflowError, TypeError)


@dataclass(frozen=True, slots=True)
class Encoded:
    """One output's payload for one frame."""

    name: str
    publisher: TopicPublisher
    payload: bytes


class PublisherSource(Protocol):
    """Where the outputs' publishers come from: the ROS transport, or a stream's outputs."""

    def publisher(self, role: str, *, express: bool = False) -> TopicPublisher: ...


class RosOutputs:
    """Declares the outputs whose key is set, and encodes a frame's payload for each."""

    def __init__(self, outputs: Outputs, dictionary: str) -> None:
        self._outputs = outputs
        self._dictionary = dictionary  # the detections' family
        self._publishers: dict[str, TopicPublisher] = {}

    def declare(self, transport: PublisherSource) -> list[TopicPublisher]:
        """Declare a publisher per output whose key is set; they are the caller's to undeclare."""
        keys = {
            DETECTIONS_TOPIC.role: self._outputs.detections_key,
            TF_TOPIC.role: self._outputs.tf_key,
        }
        for topic in ROS_OUTPUTS:
            if keys[topic.role]:
                self._publishers[topic.role] = transport.publisher(topic.role, express=True)
        return list(self._publishers.values())

    def encode(
        self, analysis: Analysis, *, stamp_ns: int, frame_id: str
    ) -> tuple[list[Encoded], list[ProcessingError]]:
        """Each declared output's payload for this frame (TF only when a tag has a pose; none
        for an output no subscriber matches), and the outputs that failed to encode (stage
        ``encode_<name>``)."""
        encoders: dict[str, Callable[[], memoryview | None]] = {
            DETECTIONS_TOPIC.role: lambda: encode_detections(
                analysis.tags,
                family=self._dictionary,
                stamp_ns=stamp_ns,
                frame_id=frame_id,
            ),
            TF_TOPIC.role: lambda: encode_tf(
                analysis.tags, prefix=self._outputs.tf_prefix, stamp_ns=stamp_ns, frame_id=frame_id
            ),
        }
        encoded: list[Encoded] = []
        failed: list[ProcessingError] = []
        for name, publisher in self._publishers.items():
            if not publisher.matched:
                continue  # nobody subscribes: neither encoded nor put
            try:
                payload = encoders[name]()
            except _ENCODE_ERRORS as err:
                failed.append(ProcessingError(f"encode_{name}", err))
                continue
            if payload is not None:
                encoded.append(Encoded(name, publisher, bytes(payload)))
        return encoded, failed
