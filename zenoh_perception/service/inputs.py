"""The service's frame inputs: which one a concrete key's samples come on (its role), and the
stream a sample's key names under that input's key expression (or list of them)."""

from __future__ import annotations

from typing import Final

import zenoh

from zenoh_perception.errors import SettingsError
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.settings import Settings
from zenoh_perception.wire.stream_keys import StreamNames

#: The inputs, by role: raw frames (msgpack attachment), sensor_msgs/Image CDR on an
#: rmw_zenoh key, sensor_msgs/CompressedImage CDR.
RAW: Final = "raw"
ROS: Final = "ros"
COMPRESSED: Final = "compressed"


def input_patterns(settings: Settings) -> dict[str, StreamNames]:
    """How each input role's keys name their streams."""
    patterns: dict[str, StreamNames] = {}
    if settings.input_key:
        patterns[RAW] = patterns[ROS] = StreamNames(settings.input_key)
    if settings.compressed_input_key:
        patterns[COMPRESSED] = StreamNames(settings.compressed_input_key)
    return patterns


def role_of(key: str, settings: Settings, ros: RosTransport) -> str:
    """The input whose samples the concrete ``key`` carries.

    Raises:
        SettingsError: ``key`` is not concrete, or neither input matches it.

    """
    if "*" in key or "$" in key:
        msg = f"{key!r} is not a concrete key"
        raise SettingsError(msg)
    concrete = zenoh.KeyExpr(key)

    def matches(keys: list[str] | tuple[str, ...]) -> bool:
        return any(zenoh.KeyExpr(k).intersects(concrete) for k in keys)

    if settings.input_key:
        if ros.rmw_zenoh and matches(ros.keys("camera")):
            return ROS
        if matches(settings.entries("input_key")):
            return RAW
    if settings.compressed_input_key and matches(ros.keys("compressed_camera")):
        return COMPRESSED
    msg = f"{key!r} matches neither input_key nor compressed_input_key"
    raise SettingsError(msg)


def name_of(role: str, key: str, patterns: dict[str, StreamNames], ros: RosTransport) -> str | None:
    """The name of the stream ``key`` (a sample's key on input ``role``) belongs to under an
    input of several streams (``patterns``: :func:`input_patterns`); None when it matches no
    input."""
    topic = key if role == RAW else ros.topic_of(key)
    names = patterns.get(role)
    return None if names is None else names.name(topic)
