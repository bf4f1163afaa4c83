"""A share group on a Zenoh session: who is in it, which streams are live, which are ours.

Zenoh does the work: liveliness tokens say who is there, liveliness subscribers with history
say who was there before and who comes and goes, a liveliness query says who is there now.
Nothing here coordinates, registers or votes: every member computes the same assignment
(:func:`zenoh_perception.sharing.assign`) from the same two sets and takes its share.

- This instance declares ``<liveliness_key>/group/<name>/<zid>`` and watches
  ``<liveliness_key>/group/<name>/*``: the members.
- It watches ``@camera/<pattern>`` for each input pattern: the streams, the concrete keys the
  cameras announce. No frame crosses the network for that.
- One thread applies the changes: it computes the assignment and calls ``take(key)`` for each
  stream it gained and ``release(key)`` for each it lost (the service subscribes to that one
  concrete key, or undeclares the subscription). Zenoh's callbacks only update the sets.

Joining: the token is declared first, then a liveliness query waits for the members and
streams already there, and only then is anything taken. The members that were there see the
token at once and release what the newcomer is given, so the newcomer takes a stream about
when its last holder has let it go. Leaving: :meth:`StreamGroup.close` releases every stream
before it undeclares the token (the others take them once it is gone). Dying: the others see
the token vanish when Zenoh drops the dead session's link (at once when its process dies on
the same machine or its socket is reset; after the session lease when the link just goes
silent: tune ``transport/link/tx/lease``).

The hand-over window: between a release and the take on the other side a frame of that
stream is answered by nobody, and when the two members see a change at different moments one
frame may be answered by both (each record names the ``instance`` that answered). Once both
have applied the change, each stream has exactly one holder.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any, Final

import zenoh

from zenoh_perception.service.logs import kv
from zenoh_perception.sharing import (
    assign,
    camera_key_of,
    camera_token_key,
    group_prefix,
    held_by,
    member_of,
    member_token_key,
)

log = logging.getLogger("zenoh_perception.service.group")

#: How long joining waits for the members and streams already there, s.
DISCOVERY_TIMEOUT_S: Final = 2.0


class StreamGroup:
    """Membership of share group ``name``; see the module doc.

    ``take`` and ``release`` are called from the group's own thread, one at a time.
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        name: str,
        liveliness_key: str,
        patterns: Sequence[str],
        take: Callable[[str], None],
        release: Callable[[str], None],
        discovery_timeout_s: float = DISCOVERY_TIMEOUT_S,
    ) -> None:
        self.name = name
        self._session = session
        self._liveliness_key = liveliness_key
        self._patterns = tuple(patterns)
        self._take, self._release = take, release
        self._discovery_timeout_s = discovery_timeout_s
        self._zid = str(session.zid())
        self._lock = threading.Lock()
        self._members: set[str] = {self._zid}
        self._streams: set[str] = set()
        self._watched: set[str] = set()  # values a subscriber reported (newer than a query)
        self._held: frozenset[str] = frozenset()
        self._changes = 0  # assignments applied that changed what this instance holds
        self._changed = threading.Event()
        self._stop = threading.Event()
        self._declared: list[Any] = []
        self._token: Any = None
        self._thread = threading.Thread(target=self._apply_loop, name="perception-group")

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> None:
        """Declare the token and the watchers, learn who is there, then start taking.

        Raises:
            zenoh.ZError: a declaration was refused (the caller reports it).

        """
        liveliness = self._session.liveliness()
        prefix = group_prefix(self._liveliness_key, self.name)
        self._token = liveliness.declare_token(
            member_token_key(self._liveliness_key, self.name, self._zid)
        )
        self._declared.append(
            liveliness.declare_subscriber(f"{prefix}/*", self._on_member, history=True)
        )
        for pattern in self._patterns:
            self._declared.append(
                liveliness.declare_subscriber(
                    camera_token_key(pattern), self._on_camera, history=True
                )
            )
        # the subscribers' history arrives in its own time: ask, and wait for the answers,
        # before taking anything (taking every stream for a moment would answer twice)
        for key, on_sample in (
            (f"{prefix}/*", self._on_member),
            *((camera_token_key(p), self._on_camera) for p in self._patterns),
        ):
            for reply in liveliness.get(key, timeout=self._discovery_timeout_s):
                if reply.ok is not None:
                    on_sample(reply.ok, answer=True)
        self._changed.set()
        self._thread.start()

    def close(self) -> None:
        """Release every stream, then leave the group (undeclare the token and watchers)."""
        self._stop.set()
        self._changed.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        for key in sorted(self._held):
            self._release(key)
        self._held = frozenset()
        for entity in [self._token, *reversed(self._declared)]:
            if entity is None:
                continue
            try:
                entity.undeclare()
            except zenoh.ZError as err:  # the session is already closed
                log.debug("event=undeclare_failed %s", kv(error=err))
        self._token = None
        self._declared.clear()

    # -- Zenoh callbacks: update the sets, never block ---------------------------------------

    def _on_member(self, sample: zenoh.Sample, *, answer: bool = False) -> None:
        member = member_of(str(sample.key_expr), self._liveliness_key, self.name)
        if member is None or member == self._zid:
            return
        self._update(self._members, member, sample.kind == zenoh.SampleKind.PUT, answer=answer)

    def _on_camera(self, sample: zenoh.Sample, *, answer: bool = False) -> None:
        stream = camera_key_of(str(sample.key_expr))
        if stream is not None:
            self._update(self._streams, stream, sample.kind == zenoh.SampleKind.PUT, answer=answer)

    def _update(self, values: set[str], value: str, present: bool, *, answer: bool) -> None:
        """Add or remove ``value``. An ``answer`` of the joining query may be older than what
        the subscribers said since (a member that died meanwhile): it never overrides them."""
        with self._lock:
            if answer and value in self._watched:
                return
            if not answer:
                self._watched.add(value)
            before = len(values)
            if present:
                values.add(value)
            else:
                values.discard(value)
            if len(values) != before:
                self._changed.set()

    # -- the group's thread ------------------------------------------------------------------

    def _apply_loop(self) -> None:
        while True:
            self._changed.wait()
            if self._stop.is_set():
                return
            self._changed.clear()
            with self._lock:
                members, streams = frozenset(self._members), frozenset(self._streams)
            held = held_by(assign(streams, members), self._zid)
            if held == self._held:
                continue
            # release first: a stream is never held twice by this instance's own doing
            for key in sorted(self._held - held):
                self._release(key)
            for key in sorted(held - self._held):
                self._take(key)
            released, taken = self._held - held, held - self._held
            self._held = held
            self._changes += 1
            log.info(
                "event=group_changed %s",
                kv(
                    group=self.name,
                    members=len(members),
                    streams=len(streams),
                    held=",".join(sorted(held)),
                    taken=",".join(sorted(taken)),
                    released=",".join(sorted(released)),
                ),
            )

    # -- observability -----------------------------------------------------------------------

    @property
    def held(self) -> frozenset[str]:
        """The streams this instance holds now."""
        return self._held

    def status(self) -> dict[str, Any]:
        """JSON-ready: the group, its members and streams as seen here, and what is held."""
        with self._lock:
            members, streams = sorted(self._members), sorted(self._streams)
        return {
            "name": self.name,
            "members": members,
            "streams": streams,
            "held": sorted(self._held),
            "changes": self._changes,
        }
