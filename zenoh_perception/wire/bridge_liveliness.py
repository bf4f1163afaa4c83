"""zenoh-bridge-ros2dds's liveliness tokens: built and parsed as the bridge itself does.

Pure building and parsing, no Zenoh session. The rules are those of the bridge's
``zenoh-plugin-ros2dds/src/liveliness_mgt.rs`` (tag 1.10.0, commit
63e9d614cdf0f64c208d79a058c90db96f7b50ce); each route a bridge serves is announced by one
token, every field one chunk:

- message publisher / subscriber (``MP`` / ``MS``):
  ``@/<zenoh id>/@ros2_lv/MP/<key>/<type>/<qos>``;
- service server / client, action server / client (``SS``, ``SC``, ``AS``, ``AC``):
  ``@/<zenoh id>/@ros2_lv/SS/<key>/<type>``;

where ``<key>`` is the route's Zenoh key (the ROS name without its leading slash, the bridge's
``namespace`` in front unless it is ``/``) and ``<type>`` the ROS type (``sensor_msgs/msg/Image``),
each ``/`` written ``§``. ``<qos>`` is ``<keyed>:<reliability>:<durability>:<history>,<depth>``
(``qos_to_key_expr``): ``K`` when the topic is keyed, then Cyclone DDS's numbers, each field
empty when the writer or reader left that policy at its default; from Iron on a fifth field
holds the USER_DATA (``typehash=RIHS01_...;``).

A bridge that sees another bridge's ``MP`` token creates a DDS writer for that topic
(``routes_mgr.rs``, ``AnnouncedMsgPub``), so ROS nodes discover the publisher before any
subscriber exists. The bridge's own parser panics on some malformed tokens (``unwrap`` on an
unescaped key, an enum number it does not know); :func:`parse_token` refuses those with
:class:`BridgeTokenError` instead, and so it does anything that is not such a token.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Final, TypeVar

from zenoh_perception.errors import MessageDecodeError

ADMIN_SPACE: Final = "@ros2_lv"
#: The ``/`` of a ROS name or type as a token writes it (``SLASH_REPLACEMSNT_CHAR``).
SLASH: Final = "§"
#: Every bridge token, of every bridge (``ke_liveliness_all``), for a liveliness subscriber.
ALL_TOKENS: Final = f"@/*/{ADMIN_SPACE}/**"
_I32_MAX: Final = 2**31 - 1
_U32_MAX: Final = 2**32 - 1
_UNSIGNED: Final = re.compile(r"\+?[0-9]+")  # Rust's u32 FromStr
_SIGNED: Final = re.compile(r"[+-]?[0-9]+")  # Rust's i32 FromStr
_NOT_IN_CHUNK: Final = frozenset("/*$#?")
_E = TypeVar("_E", bound=IntEnum)


class BridgeTokenError(MessageDecodeError):
    """A key that is not a zenoh-bridge-ros2dds liveliness token, or fields that cannot make
    one."""

    reason = "bad_bridge_token"


class Kind(Enum):
    """The interface a token announces (the fourth chunk)."""

    PUBLISHER = "MP"
    SUBSCRIBER = "MS"
    SERVICE_SERVER = "SS"
    SERVICE_CLIENT = "SC"
    ACTION_SERVER = "AS"
    ACTION_CLIENT = "AC"

    @property
    def has_qos(self) -> bool:
        return self in (Kind.PUBLISHER, Kind.SUBSCRIBER)


class Reliability(IntEnum):
    """Cyclone DDS's ``dds_reliability_kind_t``."""

    BEST_EFFORT = 0
    RELIABLE = 1


class Durability(IntEnum):
    """Cyclone DDS's ``dds_durability_kind_t``."""

    VOLATILE = 0
    TRANSIENT_LOCAL = 1
    TRANSIENT = 2
    PERSISTENT = 3


class History(IntEnum):
    """Cyclone DDS's ``dds_history_kind_t``."""

    KEEP_LAST = 0
    KEEP_ALL = 1


@dataclass(frozen=True, slots=True)
class BridgeQos:
    """The QoS a publisher or subscriber token carries; ``None`` = the policy was left at its
    default (an empty field). ``depth`` goes with ``history`` (both set or both ``None``)."""

    keyless: bool = True
    reliability: Reliability | None = None
    durability: Durability | None = None
    history: History | None = None
    depth: int | None = None
    user_data: str | None = None

    def __post_init__(self) -> None:
        if (self.history is None) != (self.depth is None):
            raise BridgeTokenError("history and depth go together")
        if self.depth is not None and not -_I32_MAX - 1 <= self.depth <= _I32_MAX:
            raise BridgeTokenError(f"depth {self.depth} does not fit an int32")
        if self.user_data is not None and (
            not _is_chunk_text(self.user_data) or ":" in self.user_data
        ):
            raise BridgeTokenError(f"user data {self.user_data!r} cannot stand in a key")

    def keyexpr(self) -> str:
        """The QoS chunk of a token, as ``qos_to_key_expr`` writes it."""
        keyed = "" if self.keyless else "K"
        reliability = "" if self.reliability is None else str(int(self.reliability))
        durability = "" if self.durability is None else str(int(self.durability))
        history = "" if self.history is None else f"{int(self.history)},{self.depth}"
        text = f"{keyed}:{reliability}:{durability}:{history}"
        # The bridge writes USER_DATA only when it runs on Iron or later.
        return text if self.user_data is None else f"{text}:{self.user_data}"

    @classmethod
    def parse(cls, text: str) -> BridgeQos:
        """A QoS chunk read as ``key_expr_to_qos`` reads it: at least four ``:`` fields, the
        first empty for keyless, a fifth (if any, and not empty) the USER_DATA; fields after
        the fifth are ignored."""
        fields = text.split(":")
        if len(fields) < 4:
            raise BridgeTokenError(f"QoS {text!r}: fewer than 4 ':' fields")
        history: History | None = None
        depth: int | None = None
        if fields[3]:
            kind, comma, number = fields[3].partition(",")
            if not comma:
                raise BridgeTokenError(f"QoS {text!r}: history without a depth")
            history = _enum(History, kind, text)
            depth = _int32(number, text)
        user_data = fields[4] if len(fields) > 4 and fields[4] else None
        return cls(
            keyless=not fields[0],
            reliability=_enum(Reliability, fields[1], text) if fields[1] else None,
            durability=_enum(Durability, fields[2], text) if fields[2] else None,
            history=history,
            depth=depth,
            user_data=user_data,
        )


@dataclass(frozen=True, slots=True)
class BridgeToken:
    """One route a bridge announces.

    ``key`` is the route's Zenoh key (``tag``, ``rover/front/image``), ``ros_type`` the ROS
    type (``sensor_msgs/msg/Image``), ``zid`` the announcing Zenoh session's id, ``qos``
    ``None`` for services and actions.
    """

    kind: Kind
    zid: str
    key: str
    ros_type: str
    qos: BridgeQos | None = None

    def __post_init__(self) -> None:
        if not _is_chunk_text(self.zid):
            raise BridgeTokenError(f"zenoh id {self.zid!r} is not one key chunk")
        for what, value in (("key", self.key), ("type", self.ros_type)):
            if not _is_concrete_keyexpr(value) or SLASH in value:
                raise BridgeTokenError(f"{what} {value!r} cannot stand in a bridge token")
        if self.kind.has_qos != (self.qos is not None):
            needs = "needs" if self.kind.has_qos else "has no"
            raise BridgeTokenError(f"a {self.kind.value} token {needs} QoS")

    def keyexpr(self) -> str:
        """The token's key expression (``new_ke_liveliness_pub`` and its siblings)."""
        head = (
            f"@/{self.zid}/{ADMIN_SPACE}/{self.kind.value}/"
            f"{self.key.replace('/', SLASH)}/{self.ros_type.replace('/', SLASH)}"
        )
        return head if self.qos is None else f"{head}/{self.qos.keyexpr()}"

    def ros_name(self, namespace: str = "/") -> str:
        """The ROS name a bridge configured with ``namespace`` gives this route
        (``key_expr_to_ros2_name``: the namespace, without its slash, is stripped as a plain
        text prefix when the key starts with it)."""
        if namespace == "/":
            return f"/{self.key}"
        stripped = _strip_prefix(self.key, namespace[1:])
        return f"/{self.key}" if stripped is None else stripped


def ros_name_to_key(ros_name: str, namespace: str = "/") -> str:
    """The Zenoh key a bridge configured with ``namespace`` gives the absolute ROS name
    ``ros_name`` (``ros2_name_to_key_expr``)."""
    if namespace == "/":
        return ros_name[1:]
    return f"{namespace[1:]}/{ros_name[1:]}"


def publisher_token(zid: str, key: str, ros_type: str, qos: BridgeQos) -> str:
    """The ``MP`` token announcing a publisher of ``ros_type`` on ``key``."""
    return BridgeToken(Kind.PUBLISHER, zid, key, ros_type, qos).keyexpr()


def parse_token(text: str) -> BridgeToken:
    """A bridge token read back; :class:`BridgeTokenError` for anything else (never another
    exception, whatever ``text`` holds)."""
    if not isinstance(text, str) or not _is_concrete_keyexpr(text):
        raise BridgeTokenError(f"{text!r} is not a concrete key expression")
    chunks = text.split("/")
    if len(chunks) < 4 or chunks[0] != "@" or chunks[2] != ADMIN_SPACE:
        raise BridgeTokenError(f"{text!r} is not a bridge liveliness token")
    try:
        kind = Kind(chunks[3])
    except ValueError:
        raise BridgeTokenError(f"{text!r}: unknown interface kind {chunks[3]!r}") from None
    expected = 7 if kind.has_qos else 6
    if len(chunks) != expected:
        raise BridgeTokenError(f"{text!r}: a {kind.value} token has {expected} chunks")
    key = chunks[4].replace(SLASH, "/")
    ros_type = chunks[5].replace(SLASH, "/")
    qos = BridgeQos.parse(chunks[6]) if kind.has_qos else None
    # BridgeToken checks the unescaped key and type are key expressions (the bridge unwraps).
    return BridgeToken(kind, chunks[1], key, ros_type, qos)


def _enum(enum: type[_E], field: str, text: str) -> _E:
    """A Cyclone DDS enum number, read as Rust reads a u32 and refused when unknown (the
    bridge's ``From`` panics there)."""
    if not _UNSIGNED.fullmatch(field) or int(field) > _U32_MAX:
        raise BridgeTokenError(f"QoS {text!r}: {field!r} is not a u32")
    try:
        return enum(int(field))
    except ValueError:
        raise BridgeTokenError(f"QoS {text!r}: no {enum.__name__} numbered {field}") from None


def _int32(field: str, text: str) -> int:
    if not _SIGNED.fullmatch(field) or not -_I32_MAX - 1 <= int(field) <= _I32_MAX:
        raise BridgeTokenError(f"QoS {text!r}: depth {field!r} is not an int32")
    return int(field)


def _is_chunk_text(text: str) -> bool:
    """Non-empty, one chunk, no wildcard or reserved character."""
    return bool(text) and not _NOT_IN_CHUNK.intersection(text)


def _is_concrete_keyexpr(text: str) -> bool:
    """A key expression without wildcards: '/'-separated non-empty chunks, none holding one
    of ``*$#?``."""
    return all(_is_chunk_text(chunk) for chunk in text.split("/"))


def _strip_prefix(text: str, prefix: str) -> str | None:
    return text[len(prefix) :] if text.startswith(prefix) else None
