"""The service's ROS 2 outputs beside ``tag``: every detection (AprilTagDetectionArray) and the
tags' transforms (TFMessage), each on the key of its setting, declared only when that key is
set. A table of :class:`~zenoh_perception.wire.messages.RosTopic`: the ROS name and type of each
output sit next to the setting of its key, for transports that need them (rmw_zenoh)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import zenoh

from zenoh_perception.errors import ProcessingError
from zenoh_perception.pipeline import Analysis
from zenoh_perception.settings import Settings
from zenoh_perception.wire.detections import DETECTIONS_TOPIC, encode_detections
from zenoh_perception.wire.messages import RosTopic
from zenoh_perception.wire.tf import TF_TOPIC, encode_tf

#: The outputs, in the order they are published on each frame.
ROS_OUTPUTS: Final = (DETECTIONS_TOPIC, TF_TOPIC)
#: The name each output is counted under (publish and processing errors).
OUTPUT_NAMES: Final = {DETECTIONS_TOPIC: "detections", TF_TOPIC: "tf"}

_ENCODE_ERRORS: Final = (struct.error, ValueError, OverflowError, TypeError)


@dataclass(frozen=True, slots=True)
class Encoded:
    """One output's payload for one frame."""

    name: str
    publisher: zenoh.Publisher
    payload: bytes


class RosOutputs:
    """Declares the outputs whose key is set, and encodes a frame's payload for each."""

    def __init__(self, settings: Settings) -> None:
        self._settings = settings
        self._publishers: dict[RosTopic, zenoh.Publisher] = {}

    def declare(self, session: zenoh.Session) -> list[zenoh.Publisher]:
        """Declare a publisher per output whose key is set; they are the caller's to undeclare."""
        for topic in ROS_OUTPUTS:
            key = getattr(self._settings, topic.setting)
            if key:
                self._publishers[topic] = session.declare_publisher(
                    key, encoding=zenoh.Encoding.APPLICATION_CDR, express=True
                )
        return list(self._publishers.values())

    def encode(
        self, analysis: Analysis, *, stamp_ns: int, frame_id: str
    ) -> tuple[list[Encoded], list[ProcessingError]]:
        """Each declared output's payload for this frame (TF only when a tag has a pose), and
        the outputs that failed to encode (stage ``encode_<name>``)."""
        encoders: dict[RosTopic, Callable[[], memoryview | None]] = {
            DETECTIONS_TOPIC: lambda: encode_detections(
                analysis.tags,
                family=self._settings.dictionary,
                stamp_ns=stamp_ns,
                frame_id=frame_id,
            ),
            TF_TOPIC: lambda: encode_tf(
                analysis.tags, prefix=self._settings.tf_prefix, stamp_ns=stamp_ns, frame_id=frame_id
            ),
        }
        encoded: list[Encoded] = []
        failed: list[ProcessingError] = []
        for topic, publisher in self._publishers.items():
            name = OUTPUT_NAMES[topic]
            try:
                payload = encoders[topic]()
            except _ENCODE_ERRORS as err:
                failed.append(ProcessingError(f"encode_{name}", err))
                continue
            if payload is not None:
                encoded.append(Encoded(name, publisher, bytes(payload)))
        return encoded, failed
