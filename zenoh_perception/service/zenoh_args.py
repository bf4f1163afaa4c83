"""Zenoh session flags, spelled as in zenoh-python's own examples.

``-c/--config FILE`` (JSON5 Zenoh config), ``-m/--mode``, ``-e/--connect`` and ``-l/--listen``
(repeatable), ``--no-multicast-scouting`` and ``--cfg KEY:VALUE`` (a JSON5 value inserted at a
config path, e.g. ``--cfg 'transport/shared_memory/enabled:true'``). Flags override the file.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Final

import zenoh

from zenoh_perception.errors import SessionError, SettingsError, zenoh_error_text
from zenoh_perception.files import MAX_TEXT_FILE_BYTES, check_nesting, read_text_file

#: rmw_zenoh's default session configuration (its DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5, as
#: its design document tabulates it): a peer that reaches the ROS 2 router (``rmw_zenohd``) on
#: this host, listens on loopback for the peer-to-peer links gossip scouting sets up, and does
#: no multicast scouting. Used with ``ros_transport = "rmw_zenoh"`` when no ``-c`` file is given.
RMW_ZENOH_SESSION_DEFAULTS: Final[Mapping[str, object]] = {
    "mode": "peer",
    "connect/endpoints": ["tcp/localhost:7447"],
    "listen/endpoints": ["tcp/localhost:0"],
    "scouting/multicast/enabled": False,
    "scouting/gossip/enabled": True,
}

#: What ``run`` sets beside Zenoh's defaults when no ``-c`` file is given (flags override it):
#: room in each link's queue of data messages for every output of a frame and of the next.
#: A frame's outputs (tag, record, detections, TF, debug image) are express messages, one
#: queue entry each; Zenoh's default queue holds 2 and drops a message that waits 1 ms for
#: room, so a frame's third output was lost whenever the transmit task had not run for 1 ms,
#: which a busy machine makes common. 16 is Zenoh's largest; entries are allocated when used.
SERVICE_SESSION_DEFAULTS: Final[Mapping[str, object]] = {
    "transport/link/tx/queue/size/data": 16,
}


def open_zenoh(conf: zenoh.Config) -> zenoh.Session:
    """``zenoh.open(conf)``.

    Raises:
        SessionError: the session cannot be opened (a listen port in use, an endpoint that
            does not parse, no router in client mode, ...), in one line.

    """
    try:
        return zenoh.open(conf)
    except zenoh.ZError as err:
        msg = f"cannot open the Zenoh session: {zenoh_error_text(err)}"
        raise SessionError(msg) from err


def add_zenoh_arguments(parser: argparse.ArgumentParser, *, mode: bool = True) -> None:
    """The session flags; without ``mode``, no ``-m`` (a command whose mode is fixed)."""
    group = parser.add_argument_group("Zenoh session")
    group.add_argument(
        "-c", "--config", type=Path, metavar="FILE", help="Zenoh configuration file (JSON5)"
    )
    if mode:
        group.add_argument(
            "-m", "--mode", choices=("peer", "client", "router"), help="Zenoh mode (default: peer)"
        )
    group.add_argument(
        "-e",
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/192.168.1.2:7447 (repeatable)",
    )
    group.add_argument(
        "-l",
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)",
    )
    group.add_argument(
        "--no-multicast-scouting",
        action="store_true",
        help="disable multicast scouting (peers then meet only through -e/-l)",
    )
    group.add_argument(
        "--cfg",
        action="append",
        default=[],
        metavar="KEY:VALUE",
        help="insert a JSON5 value at a config path, e.g. 'scouting/delay:500' (repeatable)",
    )


#: Link protocols of Zenoh's locators (``PROTOCOL/ADDRESS``).
PROTOCOLS: Final = (
    "tcp",
    "udp",
    "tls",
    "quic",
    "ws",
    "unixsock-stream",
    "unixpipe",
    "serial",
    "vsock",
)
#: Largest Zenoh configuration file read, bytes.
MAX_CONFIG_FILE_BYTES: Final = MAX_TEXT_FILE_BYTES


def check_endpoint(flag: str, endpoint: str) -> None:
    """Refuse an endpoint that is not ``PROTOCOL/ADDRESS``, with the right form in the message.

    Raises:
        SettingsError: naming ``flag`` and showing the expected form.

    """
    protocol, sep, address = endpoint.partition("/")
    if sep and protocol in PROTOCOLS and address and endpoint.isprintable():
        return
    example = f"tcp/{endpoint}" if not sep and ":" in endpoint else "tcp/192.168.1.2:7447"
    msg = (
        f"{flag} {endpoint!r}: an endpoint is PROTOCOL/ADDRESS with PROTOCOL one of "
        f"{', '.join(PROTOCOLS)}, e.g. {example}"
    )
    raise SettingsError(msg)


def _config_file(path: Path) -> zenoh.Config:
    text = read_text_file(path, "Zenoh configuration file (-c)", MAX_CONFIG_FILE_BYTES)
    check_nesting(text, f"Zenoh configuration file (-c) {path}")
    try:
        return zenoh.Config.from_json5(text)
    except zenoh.ZError as err:
        msg = f"Zenoh configuration file (-c) {path} is invalid: {zenoh_error_text(err)}"
        raise SettingsError(msg) from err


def _insert(conf: zenoh.Config, flag: str, path: str, value: str) -> None:
    check_nesting(value, f"{flag} {path}")
    try:
        conf.insert_json5(path, value)
    except zenoh.ZError as err:
        msg = f"{flag} {path}: {zenoh_error_text(err)}"
        raise SettingsError(msg) from err


def zenoh_config_from_args(
    args: argparse.Namespace, defaults: Mapping[str, object] | None = None
) -> zenoh.Config:
    """A ``zenoh.Config`` from the flags added by :func:`add_zenoh_arguments`.

    ``defaults`` (config path -> value) stand in for Zenoh's own defaults when no ``-c`` file
    is given; the flags override them either way.

    Raises:
        SettingsError: an unreadable or invalid config file (not a regular UTF-8 file of at
            most 1 MiB, nested too deep, not Zenoh's JSON5), a malformed endpoint or ``--cfg``,
            or client mode with nowhere to connect; each message names the flag.

    """
    conf = _config_file(args.config) if args.config else zenoh.Config()
    if not args.config:
        for path, value in (defaults or {}).items():
            _insert(conf, "defaults", path, json.dumps(value))
    mode = getattr(args, "mode", None)
    if mode is not None:
        _insert(conf, "-m/--mode", "mode", json.dumps(mode))
    for flag, name, endpoints in (
        ("-e/--connect", "connect/endpoints", args.connect),
        ("-l/--listen", "listen/endpoints", args.listen),
    ):
        for endpoint in endpoints:
            check_endpoint(flag, str(endpoint))
        if endpoints:
            _insert(conf, flag, name, json.dumps(endpoints))
    if args.no_multicast_scouting:
        _insert(conf, "--no-multicast-scouting", "scouting/multicast/enabled", "false")
    for item in args.cfg:
        key, sep, value = str(item).partition(":")
        if not sep or not key:
            msg = f"--cfg {item!r} is not KEY:VALUE"
            raise SettingsError(msg)
        _insert(conf, "--cfg", key, value)
    _check_client_can_connect(conf)
    return conf


def _json(conf: zenoh.Config, path: str) -> object:
    try:
        return json.loads(conf.get_json(path))
    except (zenoh.ZError, ValueError):
        return None


def _check_client_can_connect(conf: zenoh.Config) -> None:
    """A client that has no endpoint to connect to and may not scout would retry for ever.

    Raises:
        SettingsError: client mode, no connect endpoint, multicast scouting off.

    """
    if _json(conf, "mode") != "client":
        return
    endpoints = _json(conf, "connect/endpoints")
    if isinstance(endpoints, dict):  # per-mode endpoints
        endpoints = endpoints.get("client", [])
    if endpoints or _json(conf, "scouting/multicast/enabled") is not False:
        return
    msg = (
        "client mode with multicast scouting off has nowhere to connect: give the router's "
        "endpoint with -e, e.g. -e tcp/127.0.0.1:7447"
    )
    raise SettingsError(msg)
