"""rmw_zenoh's wire formats: data keys, liveliness tokens, QoS strings, GIDs and attachments.

Pure building and parsing, no Zenoh session. The rules are those of ros2/rmw_zenoh's
``docs/design.md`` (Jazzy, Kilted and Rolling share them):

- data key: ``<domain_id>/<fully qualified topic, no leading slash>/<DDS type>/<type hash>``,
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``;
- node token: ``@ros2_lv/<domain_id>/<session id>/<node id>/<node id>/NN/<enclave>/<namespace>/
  <node name>``; a publisher (``MP``) or subscription (``MS``) token goes on with
  ``/<entity id>`` in the second id's place and ``/<topic>/<DDS type>/<type hash>/<qos>``, every
  name *mangled* (each ``/`` becomes ``%``; the root namespace and enclave are ``%``);
- QoS: ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
  <liveliness>,<lease s>,<ns>`` with the numbers of ``rmw/types.h``, each left empty where it
  equals rmw_zenoh's default (reliable, volatile, keep last 42, infinite times, automatic);
- GID: XXH3-128 of the entity's token, its low 64 bits then its high 64 bits, little-endian;
- attachment of every sample: sequence number (int64 LE, from 1, per publisher), source
  timestamp (int64 LE, ns since the epoch), one byte 16, the 16-byte publisher GID.

Type hashes (RIHS01, REP 2016) are computed from the message definitions by rosbags.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import Final

import xxhash
from rosbags.typesys.store import Typestore

from zenoh_perception.errors import RmwZenohError

ADMIN_SPACE: Final = "@ros2_lv"
NODE: Final = "NN"
PUBLISHER: Final = "MP"
SUBSCRIPTION: Final = "MS"
#: The type hash position of a subscription key that matches every version of a type.
ANY_HASH: Final = "*"
GID_SIZE: Final = 16
_ATTACHMENT: Final = struct.Struct("<qqB16s")
ATTACHMENT_SIZE: Final = _ATTACHMENT.size  # 33
DOMAIN_ID_MAX: Final = 232

# ROS 2 names (design.ros2.org "Topic and Service name mapping"): tokens of letters, digits
# and underscores, not starting with a digit, no double underscore.
_NAME_PART: Final = r"[A-Za-z_][A-Za-z0-9_]*"
_NODE_NAME: Final = re.compile(_NAME_PART)
_NAMESPACE: Final = re.compile(rf"/|(?:/{_NAME_PART})+")
_RELATIVE_TOPIC: Final = re.compile(rf"{_NAME_PART}(?:/{_NAME_PART})*")


class Reliability(IntEnum):
    """``rmw_qos_reliability_policy_e``."""

    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):
    """``rmw_qos_durability_policy_e``."""

    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class History(IntEnum):
    """``rmw_qos_history_policy_e``."""

    KEEP_LAST = 1
    KEEP_ALL = 2


@dataclass(frozen=True, slots=True)
class Qos:
    """The QoS a token advertises (deadline, lifespan and liveliness stay rmw's defaults)."""

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    history: History = History.KEEP_LAST
    depth: int = 42

    def keyexpr(self) -> str:
        """The compact QoS string of a liveliness token, defaults left empty."""
        default = Qos()

        def part(value: int, default_value: int) -> str:
            return "" if value == default_value else str(int(value))

        return (
            f"{part(self.reliability, default.reliability)}:"
            f"{part(self.durability, default.durability)}:"
            f"{part(self.history, default.history)},{part(self.depth, default.depth)}:"
            ",:,:,,"
        )


#: ROS's default QoS (rclcpp/rclpy depth 10): reliable, volatile, keep last 10.
DEFAULT_QOS: Final = Qos(depth=10)
#: ROS's sensor-data QoS: best effort, volatile, keep last 5.
SENSOR_DATA_QOS: Final = Qos(reliability=Reliability.BEST_EFFORT, depth=5)


def is_node_name(name: str) -> bool:
    return bool(_NODE_NAME.fullmatch(name)) and "__" not in name


def is_namespace(namespace: str) -> bool:
    """'' (the root), '/' or an absolute name such as '/rover' or '/rover/left'."""
    return namespace == "" or (bool(_NAMESPACE.fullmatch(namespace)) and "__" not in namespace)


def is_relative_topic(name: str) -> bool:
    """A relative ROS topic name such as ``tag`` or ``zed/left/image``, the form of the
    service's keys."""
    return bool(_RELATIVE_TOPIC.fullmatch(name)) and "__" not in name


def fully_qualified(namespace: str, topic: str) -> str:
    """The fully qualified name of ``topic`` (relative, or absolute with a leading '/') in
    ``namespace``."""
    if topic.startswith("/"):
        return topic
    root = namespace.rstrip("/")
    return f"{root}/{topic}"


def mangle(name: str) -> str:
    """A name as it stands in one chunk of a token: every '/' becomes '%' ('' -> '%')."""
    return name.replace("/", "%") or "%"


def dds_type_name(ros_type: str) -> str:
    """``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(store: Typestore, ros_type: str) -> str:
    """The RIHS01 type hash of ``ros_type`` as rosidl computes it, by rosbags."""
    return store.hash_rihs01(ros_type)


def topic_key(domain_id: int, fq_topic: str, ros_type: str, hash_: str) -> str:
    """The data key of a topic; ``hash_`` may be :data:`ANY_HASH` to subscribe to every
    version of the type."""
    return f"{domain_id}/{fq_topic.lstrip('/')}/{dds_type_name(ros_type)}/{hash_}"


@dataclass(frozen=True, slots=True)
class NodeInfo:
    """The node whose tokens the service declares."""

    domain_id: int
    session_id: str  # the Zenoh session id, as Zenoh prints it
    name: str
    namespace: str = ""
    enclave: str = ""
    node_id: int = 0

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain_id}/{self.session_id}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}"
        )

    def node_token(self) -> str:
        return self._prefix(self.node_id, NODE)

    def entity_token(
        self, entity_id: int, kind: str, fq_topic: str, ros_type: str, *, hash_: str, qos: Qos
    ) -> str:
        """The token of a publisher (``MP``) or subscription (``MS``) of this node."""
        return (
            f"{self._prefix(entity_id, kind)}/{mangle(fq_topic)}/{dds_type_name(ros_type)}/"
            f"{hash_}/{qos.keyexpr()}"
        )


def gid_of(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh derives from an entity's liveliness token."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


@dataclass(frozen=True, slots=True)
class Attachment:
    """What rmw_zenoh attaches to every sample."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        return _ATTACHMENT.pack(self.sequence_number, self.source_timestamp_ns, GID_SIZE, self.gid)


def decode_attachment(data: bytes | memoryview) -> Attachment:
    """Parse an rmw_zenoh attachment.

    Raises:
        RmwZenohError: not 33 bytes, or a GID length other than 16.

    """
    if len(data) != ATTACHMENT_SIZE:
        text = f"rmw_zenoh attachment of {len(data)} bytes, not {ATTACHMENT_SIZE}"
        raise RmwZenohError(text)
    seq, stamp, gid_len, gid = _ATTACHMENT.unpack(data)
    if gid_len != GID_SIZE:
        text = f"rmw_zenoh attachment with a GID of {gid_len} bytes, not {GID_SIZE}"
        raise RmwZenohError(text)
    return Attachment(seq, stamp, gid)


@dataclass(frozen=True, slots=True)
class Token:
    """The parts of a liveliness token that tell who is where (topic parts '' for a node)."""

    domain_id: int
    session_id: str
    node_id: str
    entity_id: str
    kind: str
    enclave: str
    namespace: str
    node_name: str
    topic: str = ""
    dds_type: str = ""
    type_hash: str = ""
    qos: str = ""


def parse_token(key: str) -> Token:
    """Split a liveliness token into its parts (names demangled).

    Raises:
        RmwZenohError: not a token of rmw_zenoh's form.

    """
    parts = key.split("/")
    if len(parts) not in (9, 13) or parts[0] != ADMIN_SPACE or not parts[1].isdigit():
        text = f"not an rmw_zenoh liveliness token: {key!r}"
        raise RmwZenohError(text)

    def demangle(chunk: str) -> str:
        return chunk.replace("%", "/")

    topic = parts[9:] if len(parts) == 13 else ["", "", "", ""]
    return Token(
        int(parts[1]),
        parts[2],
        parts[3],
        parts[4],
        parts[5],
        demangle(parts[6]),
        demangle(parts[7]),
        parts[8],
        demangle(topic[0]),
        topic[1],
        topic[2],
        topic[3],
    )
