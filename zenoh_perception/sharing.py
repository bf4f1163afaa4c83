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

The keys the group meets on are built here too: a camera's announcement is a liveliness
token at ``@camera/<camera key>``, so that an instance asks for ``@camera/<input_key>``
(wildcards included) and learns every live stream without receiving a frame; a member's
token is ``<liveliness_key>/group/<name>/<zid>``.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Mapping
from typing import Final

#: First chunk of every camera's liveliness token. A verbatim chunk (``@``): no wildcard
#: matches it, so a ``**`` liveliness subscriber elsewhere never mistakes a camera for a
#: service.
CAMERA_TOKEN_PREFIX: Final = "@camera"  # noqa: S105 (a key, not a secret)
#: Chunk under the service's ``liveliness_key`` that holds the groups' member tokens.
GROUP_CHUNK: Final = "group"
#: What a group name may be: one key chunk of letters, digits, ``_``, ``.`` and ``-``.
GROUP_NAME: Final = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")


def camera_token_key(camera_key: str) -> str:
    """The liveliness token a camera publishing on ``camera_key`` declares."""
    return f"{CAMERA_TOKEN_PREFIX}/{camera_key}"


def camera_key_of(token_key: str) -> str | None:
    """The camera key a token of :func:`camera_token_key` announces (None for another key)."""
    prefix = CAMERA_TOKEN_PREFIX + "/"
    return token_key[len(prefix) :] if token_key.startswith(prefix) else None


def group_prefix(liveliness_key: str, name: str) -> str:
    """The key under which the members of group ``name`` declare their tokens."""
    return f"{liveliness_key}/{GROUP_CHUNK}/{name}"


def member_token_key(liveliness_key: str, name: str, member: str) -> str:
    """The liveliness token of ``member`` (a Zenoh id) in group ``name``."""
    return f"{group_prefix(liveliness_key, name)}/{member}"


def member_of(token_key: str, liveliness_key: str, name: str) -> str | None:
    """The member a token of :func:`member_token_key` names (None for another key)."""
    prefix = group_prefix(liveliness_key, name) + "/"
    rest = token_key[len(prefix) :] if token_key.startswith(prefix) else ""
    return rest if rest and "/" not in rest else None


def weight(member: str, stream: str) -> int:
    """The rendezvous weight of the pair: 64 bits of BLAKE2b, the same in every process
    (Python's own ``hash`` of a string is salted per process)."""
    digest = hashlib.blake2b(f"{member}\0{stream}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def assign(streams: Iterable[str], members: Iterable[str]) -> dict[str, str]:
    """Each stream's member: rendezvous hashing with bounded load (see the module doc).

    Depends only on the two sets (order and repeats do not matter); no member: no stream is
    held.
    """
    stream_set, member_set = sorted(set(streams)), sorted(set(members))
    if not member_set:
        return {}
    base, extra = divmod(len(stream_set), len(member_set))
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
