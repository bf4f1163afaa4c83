"""The zenoh-bridge-ros2dds configuration that routes exactly the service's ROS topics.

Pure: from the key settings of :data:`~zenoh_perception.wire.ros_topics.ROS_TOPICS` to the
bridge's JSON5 text. The rules are the bridge's own (zenoh-plugin-ros2dds 1.10.0):

- ``allow``: each entry is a regular expression that the plugin compiles as ``^entry$``, joins
  with ``|`` and matches against the plain ROS name (``/tag``), without the bridge's namespace
  (``src/config.rs``; announcements go through ``key_expr_to_ros2_name`` first);
- a ROS name ``/a/b`` is the Zenoh key ``a/b``, or ``<namespace>/a/b`` when the bridge's
  ``namespace`` is not ``/`` (``ros2_name_to_key_expr`` in ``src/ros2_utils.rs``).

So each key the service uses is turned back into the ROS names it stands for: its namespace
chunks removed, ``*`` one chunk, ``**`` any number of chunks, ``$*`` part of a chunk, and
``{stream}`` in an output the names of the cameras the inputs can match (their wildcard
chunks; with a list, each entry's own name). Topics the service subscribes to are the bridge's
``publishers`` (ROS -> Zenoh), topics it publishes its ``subscribers`` (Zenoh -> ROS).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Final

from zenoh_perception.errors import SettingsError
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction
from zenoh_perception.wire.stream_keys import (
    STREAM,
    Keys,
    StreamNames,
    has_wildcard,
    key_entries,
    output_key,
)

#: The settings whose keys name the cameras (their wildcards or list entries name streams).
FRAME_INPUTS: Final = ("input_key", "compressed_input_key")
_ONE_CHUNK: Final = "[^/]+"
_ANY_CHUNKS: Final = "(?:/[^/]+)*"  # '**': no chunk or several, each after its '/'
_PART_OF_CHUNK: Final = "[^/]*"
_WILD: Final = re.compile(r"(\*\*|\$\*|\*)")
# A ROS name's token (design.ros2.org, "Topic and Service name mapping"): letters, digits and
# underscores, not starting with a digit; wildcards stand for whole or partial tokens.
_TOKEN_TEXT: Final = re.compile(r"[A-Za-z0-9_]*")
_NAMESPACE: Final = re.compile(r"/|(?:/[A-Za-z_][A-Za-z0-9_]*)+")


@dataclass(frozen=True, slots=True)
class Route:
    """One ``allow`` entry: the regex, and the setting (and its key) it comes from."""

    regex: str
    setting: str
    key: str
    ros_type: str


@dataclass(frozen=True, slots=True)
class BridgeRoutes:
    """What the bridge routes: ``publishers`` ROS -> Zenoh, ``subscribers`` Zenoh -> ROS."""

    publishers: tuple[Route, ...]
    subscribers: tuple[Route, ...]


def check_namespace(namespace: str) -> str:
    """``namespace`` when it is the bridge's ``/`` or an absolute ROS namespace."""
    if not _NAMESPACE.fullmatch(namespace) or "__" in namespace:
        msg = f"namespace {namespace!r} must be '/' or an absolute ROS namespace such as '/rover1'"
        raise SettingsError(msg)
    return namespace


def key_regex(setting: str, key: str, namespace: str = "/") -> str:
    """The ``allow`` regex of the ROS names that the bridge with ``namespace`` maps onto the
    keys ``key`` matches (a key expression, perhaps with wildcards).

    Raises:
        SettingsError: ``key`` does not start with the namespace's chunks, or is no ROS name.
    """
    chunks = key.split("/")
    prefix = [c for c in namespace.split("/") if c]
    if chunks[: len(prefix)] != prefix or len(chunks) == len(prefix):
        msg = (
            f"{setting} = {key!r} does not start with the bridge's namespace {namespace!r}: the "
            f"bridge maps a ROS name /x onto the key {'/'.join([*prefix, 'x'])}"
        )
        raise SettingsError(msg)
    regex = ""
    for chunk in chunks[len(prefix) :]:
        regex += _ANY_CHUNKS if chunk == "**" else "/" + _chunk_regex(setting, key, chunk)
    return regex


def _chunk_regex(setting: str, key: str, chunk: str) -> str:
    parts = _WILD.split(chunk)
    texts = parts[0::2]
    if not all(_TOKEN_TEXT.fullmatch(t) for t in texts) or (chunk[:1].isdigit()):
        msg = (
            f"{setting} = {key!r}: {chunk!r} cannot be part of a ROS name (letters, digits and "
            "'_', not starting with a digit), so the bridge cannot route it"
        )
        raise SettingsError(msg)
    wild = {"*": _ONE_CHUNK, "$*": _PART_OF_CHUNK, "**": ".*"}
    out = [re.escape(t) if i % 2 == 0 else wild[t] for i, t in enumerate(parts)]
    return "".join(out)


def stream_name_patterns(keys: Keys) -> tuple[str, ...]:
    """The names the cameras of one input setting can have, as key patterns (``front``,
    ``*`` for one chunk, ``**`` for any; ``""``: a concrete key, one stream)."""
    entries = key_entries(keys)
    if len(entries) == 1:
        entry = entries[0]
        return ("/".join(c for c in entry.split("/") if has_wildcard(c)),)
    names = StreamNames(keys)
    return tuple(names.entry_name(entry) for entry in entries)


def bridge_routes(
    values: Mapping[str, Keys], *, ros_package: str, namespace: str = "/"
) -> BridgeRoutes:
    """The routes for the key settings ``values`` (setting name -> key, or list of keys; ``""``
    = off), each service topic of :data:`ROS_TOPICS` whose setting is given."""
    check_namespace(namespace)
    names = tuple(_unique(n for name in FRAME_INPUTS for n in _names(values.get(name, ""))))
    publishers: list[Route] = []
    subscribers: list[Route] = []
    for topic in ROS_TOPICS:
        value = values.get(topic.key_setting, "")
        routes = subscribers if topic.direction is Direction.PUBLISH else publishers
        for key in _topic_keys(value, names):
            regex = key_regex(topic.key_setting, key, namespace)
            if all(route.regex != regex for route in routes):
                routes.append(Route(regex, topic.key_setting, key, topic.type_name(ros_package)))
    return BridgeRoutes(tuple(publishers), tuple(subscribers))


def _names(value: Keys) -> tuple[str, ...]:
    return stream_name_patterns(value) if key_entries(value) else ()


def _topic_keys(value: Keys, names: tuple[str, ...]) -> list[str]:
    keys: list[str] = []
    for entry in key_entries(value):
        if STREAM in entry:
            keys += [output_key(entry, name) for name in names]
        else:
            keys.append(entry)
    return _unique(keys)


def _unique(items: Iterable[str]) -> list[str]:
    return list(dict.fromkeys(items))


def render(routes: BridgeRoutes, *, namespace: str = "/", domain: int = 0, source: str) -> str:
    """The bridge's JSON5 file for ``routes`` (``source``: where the settings came from, named
    in its header)."""
    table = [
        '//// Routed, and nothing else (`allow`: the bridge compiles each entry as "^entry$",',
        "//// joins them with '|' and matches the plain ROS name, without `namespace`):",
        "////",
        *_table("ROS -> Zenoh, the camera topics (publishers)", routes.publishers),
        *_table("Zenoh -> ROS, the service's outputs (subscribers)", routes.subscribers),
    ]
    return _TEMPLATE.format(
        source=source,
        table="\n".join(table),
        namespace=json.dumps(namespace),
        domain=domain,
        publishers=_json5_list(r.regex for r in routes.publishers),
        subscribers=_json5_list(r.regex for r in routes.subscribers),
    )


def _table(title: str, routes: Iterable[Route]) -> list[str]:
    lines = [f"////   {title}:"]
    for route in routes:
        lines.append(f"////     {route.regex}")
        lines.append(f"////         {route.setting} {route.key!r}, {route.ros_type}")
    return [*lines, "////"]


def _json5_list(items: Iterable[str]) -> str:
    body = "".join(f"\n          {json.dumps(item)}," for item in items)
    return f"[{body}\n        ]" if body else "[]"


_TEMPLATE: Final = """\
////
//// zenoh-bridge-ros2dds configuration for zenoh-perception.
//// Written by `zenoh-perception bridge-config` from {source}.
//// Write it again whenever a key changes (`zenoh-perception bridge-config -s my.toml -o
//// bridge.json5`) rather than edit it: the bridge routes nothing that `allow` does not name,
//// and a typo inside `allow` is no error, only a topic that never arrives. docs/ros2.md
//// explains every choice below.
////
////   ROS_DISTRO=jazzy zenoh-bridge-ros2dds -c config/zenoh-bridge-ros2dds.json5
////   zenoh-perception run -m client -e tcp/127.0.0.1:7447 --no-multicast-scouting
////
//// ROS_DISTRO must name the ROS nodes' distribution (humble, jazzy, ...): the bridge reads
//// their discovery messages by it, and with the wrong one sees no topic (docs/ros2.md).
////
{table}
//// A ROS name /a/b is the Zenoh key a/b, or <namespace>/a/b when `namespace` is not "/".
//// Payloads are whole CDR samples with their encapsulation header, both ways.
////
{{
  plugins: {{
    ros2dds: {{
      nodename: "zenoh_bridge_ros2dds",
      namespace: {namespace},
      //// Only a fallback: --domain, which defaults to ROS_DOMAIN_ID, overrides it.
      domain: {domain},
      //// ros_localhost_only / ros_automatic_discovery_range are left to the environment
      //// (ROS_LOCALHOST_ONLY, ROS_AUTOMATIC_DISCOVERY_RANGE): the bridge reads them there.
      allow: {{
        //// ROS -> Zenoh: read while a Zenoh subscriber matches the key (the service runs).
        publishers: {publishers},
        //// Zenoh -> ROS: offered to ROS once a ROS subscriber exists, or at once when the
        //// service announces its outputs (bridge_announce, on by default).
        subscribers: {subscribers},
        service_servers: [],
        service_clients: [],
        action_servers: [],
        action_clients: [],
      }},
      //// No pub_max_frequencies: on a large image topic it stops delivery altogether
      //// (zenoh-plugin-ros2dds#371); lower the camera's own rate instead.
      //// Drop camera frames when Zenoh is congested rather than back-pressure the camera.
      reliable_routes_blocking: false,
    }},
  }},
  //// The Zenoh router the service, `status` and `replay` connect to (-e tcp/<host>:7447).
  mode: "router",
  listen: {{
    endpoints: ["tcp/0.0.0.0:7447"],
  }},
  //// No multicast scouting: the bridge joins no other router or bridge on its own.
  scouting: {{
    multicast: {{
      enabled: false,
    }},
  }},
}}
"""
