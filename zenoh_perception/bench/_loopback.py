"""Loopback Zenoh peers for the benchmarks (and the tests): free ports, multicast off."""

from __future__ import annotations

import json
import socket
from collections.abc import Sequence

import zenoh


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def loopback_endpoint() -> str:
    """``tcp/127.0.0.1:PORT`` with a port that was free a moment ago."""
    return f"tcp/127.0.0.1:{free_port()}"


def loopback_config(
    *, mode: str = "peer", listen: Sequence[str] = (), connect: Sequence[str] = ()
) -> zenoh.Config:
    """A Zenoh config that meets others only through ``listen`` / ``connect`` (multicast
    scouting off)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf
