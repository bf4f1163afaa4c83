"""The service's frame inputs: which one a concrete key's samples come on (its role), and the
stream a sample's key names under that input's key expression."""

from __future__ import annotations

from typing import Final

import zenoh

from zenoh_perception.errors import SettingsError
from zenoh_perception.service.ros_transport import RosTransport
from zenoh_perception.settings import Settings
from zenoh_perception.wire.stream_keys import stream_name

#: The inputs, by role: raw frames (msgpack attachment), sensor_msgs/Image CDR on an
#: rmw_zenoh key, sensor_msgs/CompressedImage CDR.
RAW: Final = "raw"
ROS: Final = "ros"
COMPRESSED: Final = "compressed"


def input_patterns(settings: Settings) -> dict[str, str]:
    """The key expression whose chunks name the streams, by input role."""
    patterns: dict[str, str] = {}
    if settings.input_key:
        patterns[RAW] = settings.input_key
        patterns[ROS] = settings.input_key
    if settings.compressed_input_key:
        patterns[COMPRESSED] = settings.compressed_input_key
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
    if settings.input_key:
        if ros.rmw_zenoh and zenoh.KeyExpr(ros.key("camera")).intersects(concrete):
            return ROS
        if zenoh.KeyExpr(settings.input_key).intersects(concrete):
            return RAW
    compressed = ros.key("compressed_camera") if settings.compressed_input_key else ""
    if compressed and zenoh.KeyExpr(compressed).intersects(concrete):
        return COMPRESSED
    msg = f"{key!r} matches neither input_key nor compressed_input_key"
    raise SettingsError(msg)


def name_of(role: str, key: str, patterns: dict[str, str], ros: RosTransport) -> str | None:
    """The name of the stream ``key`` (a sample's key on input ``role``) belongs to under a
    wildcard input (``patterns``: :func:`input_patterns`); None when it matches no input."""
    topic = key if role == RAW else ros.topic_of(key)
    return stream_name(patterns.get(role, ""), topic)
