"""Which instance of a share group holds which stream: pure, no Zenoh, no logging.

Instances of one group (``share_group``) divide the live streams (the concrete camera keys)
among themselves with no coordinator: each computes :func:`assign` from the same two sets, the
streams the cameras announce and the members the group's liveliness tokens show, and takes
what it is given. The same sets give the same answer in every process.

The assignment is rendezvous (highest-random-weight) hashing with bounded load. Every pair
(member, stream) has a weight, a hash of both names. The pairs are taken from the heaviest
down; a stream goes to the member of its pair unless that member is full. With ``N`` streams
and ``M`` members, ``N = q * M + r``: a member is full at ``q + 1`` streams, and at ``q`` once
``r`` members hold ``q + 1``. So every member ends with ``floor(N / M)`` or ``ceil(N / M)``
streams, and where plain rendezvous hashing is already that balanced (each stream with its
heaviest member) the answer is plain rendezvous hashing: a member that leaves gives up only
its own streams, one that joins takes only its own. Where the bound binds, a change of
members can also move a few streams between members that stay (docs/benchmarks.md measures
how many).

The keys the group meets on are built and read here too: a camera's announcement is a
liveliness token at ``@camera/<camera key>``, so that an instance asks for
``@camera/<input_key>`` (wildcards included) and learns every live stream without receiving a
frame; a member's token is ``<liveliness_key>/group/<name>/member/<zid>/<fingerprint>`` and
its heartbeat a put on ``<liveliness_key>/group/<name>/beat/<zid>``.

Anyone on the network may declare a token: every key read here is untrusted input. A reader
either returns what the key says or raises :class:`~zenoh_perception.errors.AnnouncementError`
naming the reason (counted by the caller); nothing else raises. :class:`LiveStreams` keeps the
announced streams within a bound, each stream name once.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Mapping
from typing import Final

from zenoh_perception.errors import AnnouncementError

#: First chunk of every camera's liveliness token. A verbatim chunk (``@``): no wildcard
#: matches it, so a ``**`` liveliness subscriber elsewhere never mistakes a camera for a
#: service.
CAMERA_TOKEN_PREFIX: Final = "@camera"  # noqa: S105 (a key, not a secret)
#: Chunk under the service's ``liveliness_key`` that holds the groups' member tokens.
GROUP_CHUNK: Final = "group"
#: What a group name may be: one key chunk of letters, digits, ``_``, ``.`` and ``-``.
GROUP_NAME: Final = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")


#: Bounds of an announced camera key of its own (whatever the input): longer keys or keys of
#: more chunks are ignored before any matching runs on them.
MAX_ANNOUNCED_KEY_CHARS: Final = 256
MAX_ANNOUNCED_CHUNKS: Final = 16
#: Most live announced streams a group member keeps; further announcements are counted only.
MAX_ANNOUNCED: Final = 1024
#: Most members a group member keeps track of; past that, a new member token replaces the
#: member silent the longest (none silent: it is counted only).
MAX_MEMBERS: Final = 256
#: The settings every member of a group must share, in the order of the fingerprint's fields.
GROUP_SETTINGS: Final = (
    "input_key",
    "compressed_input_key",
    "max_streams",
    "dictionary",
    "ros_transport",
)
_MEMBER_CHUNK: Final = "member"
_BEAT_CHUNK: Final = "beat"
_ZID: Final = re.compile(r"[0-9a-f]{1,32}")
_FIELD: Final = re.compile(r"[0-9a-f]{8}")


def camera_token_key(camera_key: str) -> str:
    """The liveliness token a camera publishing on ``camera_key`` declares."""
    return f"{CAMERA_TOKEN_PREFIX}/{camera_key}"


def camera_key_of(token_key: str) -> str | None:
    """The camera key a token of :func:`camera_token_key` announces (None for another key)."""
    prefix = CAMERA_TOKEN_PREFIX + "/"
    return token_key[len(prefix) :] if token_key.startswith(prefix) else None


def check_announced_key(key: str) -> str:
    """``key`` (a camera key read from a token) when it may be a stream's key: concrete and
    within :data:`MAX_ANNOUNCED_KEY_CHARS` and :data:`MAX_ANNOUNCED_CHUNKS`.

    Raises:
        AnnouncementError: ``not_concrete``, ``too_long`` or ``too_many_chunks``.

    """
    if len(key) > MAX_ANNOUNCED_KEY_CHARS:
        raise AnnouncementError("too_long", key)
    if key.count("/") >= MAX_ANNOUNCED_CHUNKS:
        raise AnnouncementError("too_many_chunks", key)
    # a wildcard, a '$' or an empty chunk is no camera's key (subscribing it would be a
    # subscription to many)
    if not key or any(c in key for c in "*$?#") or "" in key.split("/"):
        raise AnnouncementError("not_concrete", key)
    return key


def group_prefix(liveliness_key: str, name: str) -> str:
    """The key under which the members of group ``name`` declare their tokens."""
    return f"{liveliness_key}/{GROUP_CHUNK}/{name}"


def members_key(liveliness_key: str, name: str) -> str:
    """The key expression of every member token of group ``name``."""
    return f"{group_prefix(liveliness_key, name)}/{_MEMBER_CHUNK}/*/*"


def member_token_key(liveliness_key: str, name: str, member: str, fingerprint: str) -> str:
    """The liveliness token of ``member`` (a Zenoh id) in group ``name``, with the
    :func:`fingerprint` of its settings."""
    return f"{group_prefix(liveliness_key, name)}/{_MEMBER_CHUNK}/{member}/{fingerprint}"


def member_of(token_key: str, liveliness_key: str, name: str) -> tuple[str, str]:
    """The member (a Zenoh id) and fingerprint a token of :func:`member_token_key` names.

    Raises:
        AnnouncementError: ``bad_member_token``: not such a token, or its id or fingerprint
            is malformed.

    """
    prefix = f"{group_prefix(liveliness_key, name)}/{_MEMBER_CHUNK}/"
    parts = token_key[len(prefix) :].split("/") if token_key.startswith(prefix) else []
    if len(parts) != 2 or not _ZID.fullmatch(parts[0]) or not _fingerprint_fields(parts[1]):
        raise AnnouncementError("bad_member_token", token_key)
    return parts[0], parts[1]


def beat_key(liveliness_key: str, name: str, member: str) -> str:
    """The key of ``member``'s heartbeat in group ``name``."""
    return f"{group_prefix(liveliness_key, name)}/{_BEAT_CHUNK}/{member}"


def beats_key(liveliness_key: str, name: str) -> str:
    """The key expression of every heartbeat of group ``name``."""
    return f"{group_prefix(liveliness_key, name)}/{_BEAT_CHUNK}/*"


def beat_of(key: str, liveliness_key: str, name: str) -> str:
    """The member whose heartbeat came on ``key``.

    Raises:
        AnnouncementError: ``bad_beat``: not a heartbeat key, or its id is malformed.

    """
    prefix = f"{group_prefix(liveliness_key, name)}/{_BEAT_CHUNK}/"
    member = key[len(prefix) :] if key.startswith(prefix) else ""
    if not _ZID.fullmatch(member):
        raise AnnouncementError("bad_beat", key)
    return member


def fingerprint(values: Mapping[str, str]) -> str:
    """One key chunk saying what a member serves: a 32-bit hash of each of
    :data:`GROUP_SETTINGS` (``values``: each setting as text), joined by ``.``, so that two
    fingerprints tell which settings differ (:func:`differing`)."""
    return ".".join(
        hashlib.blake2b(values[n].encode(), digest_size=4).hexdigest() for n in GROUP_SETTINGS
    )


def _fingerprint_fields(text: str) -> list[str]:
    fields = text.split(".")
    if len(fields) != len(GROUP_SETTINGS) or not all(_FIELD.fullmatch(f) for f in fields):
        return []
    return fields


def differing(mine: str, theirs: str) -> list[str]:
    """The settings in which two well-formed fingerprints differ (none: they agree)."""
    pairs = zip(_fingerprint_fields(mine), _fingerprint_fields(theirs), strict=False)
    return [name for name, (a, b) in zip(GROUP_SETTINGS, pairs, strict=False) if a != b]


class LiveStreams:
    """The live announced streams: each concrete key with its stream's name, each name at
    most once, from at most ``bound`` live tokens (a camera may be announced by several: a
    topic with two publishers). Memory follows the live announcements, never the ones seen
    before. Not thread-safe (the caller locks)."""

    def __init__(self, bound: int = MAX_ANNOUNCED) -> None:
        self._bound = bound
        self._names: dict[str, str] = {}  # key -> name
        self._keys: dict[str, str] = {}  # name -> key
        self._tokens: dict[str, str] = {}  # token -> the key it announces
        self._count: dict[str, int] = {}  # key -> live tokens announcing it

    def add(self, key: str, name: str, token: str | None = None) -> bool:
        """Add the stream ``token`` (default: ``key`` itself) announces; False when the
        stream was there already.

        Raises:
            AnnouncementError: ``name_collision`` (another live key has that stream name) or
                ``too_many_announced`` (``bound`` tokens are live).

        """
        token = key if token is None else token
        if token in self._tokens:
            return False
        if len(self._tokens) >= self._bound:
            raise AnnouncementError("too_many_announced", key)
        if key not in self._names and name in self._keys:
            raise AnnouncementError("name_collision", key)
        self._tokens[token] = key
        count = self._count.get(key, 0)
        self._count[key] = count + 1
        if count:
            return False
        self._names[key], self._keys[name] = name, key
        return True

    def remove(self, token: str) -> bool:
        """Forget a token; True when its stream went with it (no other token announces it)."""
        key = self._tokens.pop(token, None)
        if key is None:
            return False
        count = self._count.pop(key) - 1
        if count:
            self._count[key] = count
            return False
        del self._keys[self._names.pop(key)]
        return True

    def keys(self) -> frozenset[str]:
        """The live streams' keys."""
        return frozenset(self._names)

    def __len__(self) -> int:
        return len(self._names)


def weight(member: str, stream: str) -> int:
    """The rendezvous weight of the pair: 64 bits of BLAKE2b, the same in every process
    (Python's own ``hash`` of a string is salted per process)."""
    digest = hashlib.blake2b(f"{member}\0{stream}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def assign(
    streams: Iterable[str], members: Iterable[str], *, capacity: int | None = None
) -> dict[str, str]:
    """Each stream's member: rendezvous hashing with bounded load (see the module doc).

    With ``capacity`` no member holds more than that many streams: past ``capacity`` times
    the members, streams are left without a holder. Depends only on the two sets and
    ``capacity`` (order and repeats do not matter); no member: no stream is held.
    """
    stream_set, member_set = sorted(set(streams)), sorted(set(members))
    if not member_set:
        return {}
    base, extra = divmod(len(stream_set), len(member_set))
    if capacity is not None and base + (extra > 0) > capacity:
        base, extra = capacity, 0
    pairs = sorted(((weight(m, s), s, m) for s in stream_set for m in member_set), reverse=True)
    load = dict.fromkeys(member_set, 0)
    holder: dict[str, str] = {}
    full_at_ceiling = 0
    for _weight, stream, member in pairs:
        if stream in holder:
            continue
        held = load[member]
        if held < base or (held == base and full_at_ceiling < extra):
            holder[stream] = member
            load[member] = held + 1
            full_at_ceiling += held == base
            if len(holder) == len(stream_set):
                break
    return holder


def held_by(assignment: Mapping[str, str], member: str) -> frozenset[str]:
    """The streams ``assignment`` gives ``member``."""
    return frozenset(s for s, m in assignment.items() if m == member)
