"""``zenoh-perception bridge-config``: the zenoh-bridge-ros2dds file for the given settings."""

from __future__ import annotations

import sys
from pathlib import Path

from zenoh_perception.errors import SettingsError
from zenoh_perception.settings import RosTransportKind, Settings
from zenoh_perception.wire.bridge_config import bridge_routes, render


def main(
    settings: Settings, *, source: str, namespace: str, domain: int, output: Path | None
) -> int:
    """Write the bridge's JSON5 for ``settings`` to ``output`` (stdout when None)."""
    if settings.ros.ros_transport is not RosTransportKind.BRIDGE:
        msg = "ros_transport is not 'bridge': the service needs no zenoh-bridge-ros2dds then"
        raise SettingsError(msg)
    routes = bridge_routes(
        settings.topic_keys(), ros_package=settings.ros.ros_package, namespace=namespace
    )
    text = render(routes, namespace=namespace, domain=domain, source=source)
    if output is None:
        sys.stdout.write(text)
    else:
        output.write_text(text, encoding="utf-8")
    return 0
