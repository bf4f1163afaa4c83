"""Loopback Zenoh peers for the benchmarks (and the tests): free ports, multicast off."""

from __future__ import annotations

import json
import random
import socket
from collections.abc import Sequence
from pathlib import Path

import zenoh

#: Where Linux says its ephemeral ports (bind to port 0, outgoing connections) are taken from.
_PORT_RANGE = Path("/proc/sys/net/ipv4/ip_local_port_range")
#: How many ports below the ephemeral range the choice is made among.
_SPAN = 12_000


def _ephemeral_low() -> int:
    try:
        return int(_PORT_RANGE.read_text(encoding="ascii").split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago.

    Chosen at random below the kernel's ephemeral range, so that between this check and the
    bind that uses it, neither an outgoing connection nor another process's bind to port 0
    takes it, and two processes choosing at once (tests in parallel) rarely pick the same.
    """
    low = _ephemeral_low()
    first = max(1024, low - _SPAN)
    for _ in range(100 if low - first >= 1000 else 0):
        port = random.randrange(first, low)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue  # in use: another one
            return port
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        chosen: int = sock.getsockname()[1]
        return chosen


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
