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


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("Zenoh session")
    group.add_argument(
        "-c", "--config", type=Path, metavar="FILE", help="Zenoh configuration file (JSON5)"
    )
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


def zenoh_config_from_args(
    args: argparse.Namespace, defaults: Mapping[str, object] | None = None
) -> zenoh.Config:
    """A ``zenoh.Config`` from the flags added by :func:`add_zenoh_arguments`.

    ``defaults`` (config path -> value) stand in for Zenoh's own defaults when no ``-c`` file
    is given; the flags override them either way.

    Raises:
        SettingsError: unreadable config file or a malformed ``--cfg``.

    """
    try:
        conf = zenoh.Config.from_file(str(args.config)) if args.config else zenoh.Config()
        if not args.config:
            for path, value in (defaults or {}).items():
                conf.insert_json5(path, json.dumps(value))
        if args.mode is not None:
            conf.insert_json5("mode", json.dumps(args.mode))
        if args.connect:
            conf.insert_json5("connect/endpoints", json.dumps(args.connect))
        if args.listen:
            conf.insert_json5("listen/endpoints", json.dumps(args.listen))
        if args.no_multicast_scouting:
            conf.insert_json5("scouting/multicast/enabled", json.dumps(False))
        for item in args.cfg:
            key, sep, value = str(item).partition(":")
            if not sep or not key:
                msg = f"--cfg {item!r} is not KEY:VALUE"
                raise SettingsError(msg)
            conf.insert_json5(key, value)
    except zenoh.ZError as err:
        msg = f"invalid Zenoh configuration: {zenoh_error_text(err)}"
        raise SettingsError(msg) from err
    return conf
