"""A share group on a Zenoh session: who is in it, which streams are live, which are ours.

Zenoh does the work: liveliness tokens say who is there, liveliness subscribers with history
say who was there before and who comes and goes, a liveliness query says who is there now.
Nothing here coordinates, registers or votes: every member computes the same assignment
(:func:`zenoh_perception.sharing.assign`) from the same two sets and takes its share.

- This instance declares ``<liveliness_key>/group/<name>/member/<zid>/<fingerprint>`` and
  watches the other member tokens. The fingerprint says what it serves (the settings of
  :data:`~zenoh_perception.sharing.GROUP_SETTINGS`): a member whose fingerprint differs is
  left out of the assignment and named, with the settings that differ, in the log and the
  status; an instance that finds one when it joins refuses to start (``SettingsError``).
- A token proves a Zenoh session, not a service: members put a heartbeat on
  ``<liveliness_key>/group/<name>/beat/<zid>`` that their worker loop drives (:meth:`beat`,
  called between frames and every poll while idle), not Zenoh's runtime. A member counts only
  while its heartbeat is fresher than ``silent_after_s``: a bare token, or an instance whose
  Python is wedged while its Zenoh runtime lives, loses its streams to the others. A member
  whose camera is merely silent keeps beating (its workers poll), and a busy one beats between
  frames (a 400 ms frame is far within the bound).
- It watches each camera source (:class:`CameraSource`: ``@camera/<pattern>`` for each input
  pattern): the streams, the concrete keys the cameras announce. No frame crosses the network
  for that. Every announced key is untrusted: one that is not concrete, too long, matches no
  input or would share its stream's name with another is ignored, counted by reason and
  logged at a limited rate; at most :data:`~zenoh_perception.sharing.MAX_ANNOUNCED` live
  streams are kept, and a member holds at most ``capacity`` (``max_streams``).
- One thread applies the changes: it computes the assignment and calls ``take(key)`` for each
  stream it gained and ``release(key)`` for each it lost (the service subscribes to that one
  concrete key, or undeclares the subscription). Zenoh's callbacks only update the sets. A
  crash of that thread is no silent end: it is logged and ``failed`` is set (the service exits
  non-zero).

Joining: the token is declared first, then a liveliness query waits for the members and
streams already there, then their heartbeats (each member beats at once when it sees a new
token), and only then is anything taken. The members that were there release what the
newcomer is given once its first heartbeat comes, so the newcomer takes a stream about when
its last holder has let it go. Leaving: :meth:`StreamGroup.close` releases every stream before
it undeclares the token (the others take them once it is gone). Dying: the others see the
token vanish when Zenoh drops the dead session's link (at once when its process dies on the
same machine or its socket is reset; after the session lease when the link just goes silent:
tune ``transport/link/tx/lease``), or its heartbeat stop.

The hand-over window: between a release and the take on the other side a frame of that
stream is answered by nobody, and when the two members see a change at different moments one
frame may be answered by both (each record names the ``instance`` that answered). Once both
have applied the change, each stream has exactly one holder.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, Final

import zenoh

from zenoh_perception.errors import (
    AnnouncementError,
    PerceptionError,
    RmwZenohError,
    SettingsError,
)
from zenoh_perception.service.logs import LimitedLog, kv
from zenoh_perception.service.stats import LogGate
from zenoh_perception.service.threads import guarded_thread
from zenoh_perception.settings import RosTransportKind, Settings
from zenoh_perception.settings.sections import Inputs, Ros
from zenoh_perception.sharing import (
    GROUP_SETTINGS,
    MAX_ANNOUNCED,
    MAX_MEMBERS,
    LiveStreams,
    assign,
    beat_key,
    beat_of,
    beats_key,
    camera_key_of,
    camera_token_key,
    check_announced_key,
    differing,
    fingerprint,
    held_by,
    member_of,
    member_token_key,
    members_key,
)
from zenoh_perception.wire.bridge_liveliness import ADMIN_SPACE as BRIDGE_ADMIN
from zenoh_perception.wire.bridge_liveliness import BridgeTokenError
from zenoh_perception.wire.bridge_liveliness import Kind as BridgeKind
from zenoh_perception.wire.bridge_liveliness import parse_token as parse_bridge_token
from zenoh_perception.wire.rmw_zenoh import ADMIN_SPACE as RMW_ADMIN
from zenoh_perception.wire.rmw_zenoh import PUBLISHER as RMW_PUBLISHER
from zenoh_perception.wire.rmw_zenoh import dds_type_name, topic_key
from zenoh_perception.wire.rmw_zenoh import parse_token as parse_rmw_token
from zenoh_perception.wire.stream_keys import StreamNames, key_entries

log = logging.getLogger(__name__)

#: How long joining waits for the members and streams already there, s.
DISCOVERY_TIMEOUT_S: Final = 2.0
#: Period of a member's heartbeat, s (at most: it is put sooner when a member joins).
BEAT_PERIOD_S: Final = 0.2
#: A member whose last heartbeat is older than this is silent: left out until it beats
#: again, s. Far above a busy frame (hundreds of ms) and a scheduling hiccup on a loaded
#: machine; with the check period, a silent holder loses its streams within 3 s.
SILENT_AFTER_S: Final = 2.5
#: Period at which the group's thread looks for silent members, s.
CHECK_S: Final = 0.25


@dataclass(frozen=True, slots=True)
class CameraSource:
    """Where a group learns streams: the liveliness key expression it watches (``watch``),
    and what a token there announces (``read``: the token's key -> the stream's concrete key
    and its name; None for a ROS graph's publisher that is not one of the cameras served,
    which is no announcement at all; or :class:`~zenoh_perception.errors.AnnouncementError`;
    nothing else may raise)."""

    watch: str
    read: Callable[[str], tuple[str, str] | None]


def settings_fingerprint(settings: Settings) -> str:
    """The fingerprint of what ``settings`` serve in a group (a list of keys as one text)."""
    inputs = settings.inputs
    values = {
        "input_key": "\n".join(inputs.input_entries),
        "compressed_input_key": "\n".join(key_entries(inputs.compressed_input_key)),
        "max_streams": str(inputs.max_streams),
        "dictionary": settings.detection.dictionary,
        "ros_transport": str(settings.ros.ros_transport),
    }
    assert tuple(values) == GROUP_SETTINGS, "the fingerprint's fields, in their order"
    return fingerprint(values)


#: The ROS type of each frame input's topic.
_CAMERA_TYPES: Final = {
    "input_key": "sensor_msgs/msg/Image",
    "compressed_input_key": "sensor_msgs/msg/CompressedImage",
}


def camera_sources(inputs: Inputs, ros: Ros) -> list[CameraSource]:
    """Where the cameras of ``inputs`` are announced, each read as the service
    names its streams (raw and compressed streams apart):

    - ``@camera/<entry>`` for each entry of each frame input (this project's cameras);
    - zenoh-bridge-ros2dds's publisher route tokens (a ROS camera behind a bridge: the key
      it publishes on is the stream's);
    - with ``ros_transport = "rmw_zenoh"``, rmw_zenoh's publisher tokens in the configured
      domain (the stream is the topic's data key).
    """
    named = {role: StreamNames(keys) for role, keys in inputs.frame_inputs if keys}
    sources = [
        CameraSource(camera_token_key(entry), partial(_read_camera_token, role, names))
        for role, names in named.items()
        for entry in names.entries
    ]
    by_type = {_CAMERA_TYPES[role]: (role, names) for role, names in named.items()}
    sources.append(CameraSource(BRIDGE_PUBLISHERS, partial(_read_bridge_token, by_type)))
    if ros.ros_transport is RosTransportKind.RMW_ZENOH:
        domain = ros.ros_domain_id
        by_dds = {dds_type_name(t): (t, *names) for t, names in by_type.items()}
        read = partial(_read_rmw_token, by_dds, domain, ros.ros_namespace)
        sources.append(CameraSource(f"{RMW_ADMIN}/{domain}/*/*/*/{RMW_PUBLISHER}/**", read))
    return sources


#: Every publisher route token of every zenoh-bridge-ros2dds (its key and type are one chunk).
BRIDGE_PUBLISHERS: Final = f"@/*/{BRIDGE_ADMIN}/{BridgeKind.PUBLISHER.value}/*/*/*"


def _stream(role: str, names: StreamNames, key: str, token: str) -> tuple[str, str]:
    """The stream of ``key`` (the part its input names) on input ``role``."""
    name = names.name(key)
    if name is None:
        raise AnnouncementError("no_match", token)
    return name, f"{role}:{name}"


def _read_camera_token(role: str, names: StreamNames, token: str) -> tuple[str, str]:
    key = camera_key_of(token)
    if key is None:
        raise AnnouncementError("no_match", token)
    return key, _stream(role, names, check_announced_key(key), token)[1]


def _read_bridge_token(
    by_type: dict[str, tuple[str, StreamNames]], token: str
) -> tuple[str, str] | None:
    """A bridge's route of a camera served, or None: a ROS graph routes many topics (other
    types, other cameras, the service's own outputs) and none of them is announced to a group."""
    try:
        route = parse_bridge_token(token)
    except BridgeTokenError as err:
        raise AnnouncementError("bad_bridge_token", token) from err
    camera = by_type.get(route.ros_type)
    if route.kind is not BridgeKind.PUBLISHER or camera is None:
        return None
    key = check_announced_key(route.key)
    role, names = camera
    return None if names.name(key) is None else (key, _stream(role, names, key, token)[1])


def _read_rmw_token(
    by_dds: dict[str, tuple[str, str, StreamNames]], domain: int, namespace: str, token: str
) -> tuple[str, str] | None:
    """An rmw_zenoh publisher of a camera served, or None (any other publisher of the graph)."""
    if any(c in token for c in "*$?#"):
        raise AnnouncementError("not_concrete", token)
    try:
        publisher = parse_rmw_token(token)
    except (RmwZenohError, ValueError) as err:  # int() of a digit str.isdigit() admits
        raise AnnouncementError("bad_rmw_zenoh_token", token) from err
    camera = by_dds.get(publisher.dds_type)
    prefix = namespace.rstrip("/") + "/"
    if (
        publisher.kind != RMW_PUBLISHER
        or publisher.domain_id != domain
        or camera is None
        or not publisher.topic.startswith(prefix)
    ):
        return None
    ros_type, role, names = camera
    key = topic_key(domain, publisher.topic, ros_type, publisher.type_hash)
    topic = publisher.topic[len(prefix) :]
    if names.name(topic) is None:
        return None
    return check_announced_key(key), _stream(role, names, topic, token)[1]


def _direct(callback: Callable[[zenoh.Sample], None]) -> zenoh.handlers.Callback[zenoh.Sample]:
    """``callback`` called on the Zenoh thread that receives the sample."""
    return zenoh.handlers.Callback(callback, indirect=False)


@dataclass(slots=True)
class _Member:
    fingerprint: str
    beat: float = -1e18  # monotonic s of its last heartbeat: none yet
    seen: float = field(default_factory=time.monotonic)  # when its token came

    @property
    def heard(self) -> float:
        """When it last said something (its token, or a heartbeat)."""
        return max(self.beat, self.seen)


class StreamGroup:
    """Membership of share group ``name``; see the module doc.

    ``take`` and ``release`` are called from the group's own thread, one at a time; ``take``
    may raise a :class:`~zenoh_perception.errors.PerceptionError` (counted, retried at the
    next check). ``fingerprint`` is :func:`~zenoh_perception.sharing.fingerprint` of this
    instance's settings; ``capacity`` the most streams a member holds.
    """

    def __init__(
        self,
        session: zenoh.Session,
        *,
        name: str,
        liveliness_key: str,
        sources: Sequence[CameraSource],
        fingerprint: str,
        capacity: int,
        take: Callable[[str], None],
        release: Callable[[str], None],
        gate: LogGate,
        failed: threading.Event,
        discovery_timeout_s: float = DISCOVERY_TIMEOUT_S,
        silent_after_s: float = SILENT_AFTER_S,
    ) -> None:
        self.name = name
        self._session = session
        self._liveliness_key = liveliness_key
        self._sources = tuple(sources)
        self._fingerprint = fingerprint
        self._capacity = capacity
        self._take, self._release = take, release
        self._log = LimitedLog(log, gate)
        self._discovery_timeout_s = discovery_timeout_s
        self._silent_after_s = silent_after_s
        self._zid = str(session.zid())
        self._lock = threading.Lock()
        self._members: dict[str, _Member] = {}  # the others with a token
        self._streams = LiveStreams(MAX_ANNOUNCED)
        # while joining: the values a subscriber reported (newer than the query's answers)
        self._watched: dict[str, bool] | None = {}
        self._held: frozenset[str] = frozenset()
        self._live: frozenset[str] = frozenset({self._zid})
        self._changes = 0  # assignments applied that changed what this instance holds
        self._evictions = 0  # members left out because their heartbeat stopped
        self._ignored: Counter[str] = Counter()
        self._ignored_tokens: set[str] = set()  # live tokens ignored (each counted once)
        self._changed = threading.Event()
        self._beaten = threading.Event()  # a member's first heartbeat came (joining waits)
        self._stop = threading.Event()
        self._declared: list[Any] = []
        self._token: Any = None
        self._beat_pub: zenoh.Publisher | None = None
        self._next_beat = 0.0
        self._beat_due = True
        # a crash of the group's thread is logged and fails the service (never a silent end:
        # the instance would keep its streams, or never take its share again)
        self._thread = guarded_thread(self._apply_loop, name="perception-group", failed=failed)

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> None:
        """Declare the token, the heartbeat and the watchers, learn who is there, then start
        taking.

        Raises:
            zenoh.ZError: a declaration was refused (the caller reports it).
            SettingsError: a member already there serves with other settings (named).

        """
        liveliness = self._session.liveliness()
        lk, name = self._liveliness_key, self.name
        self._beat_pub = self._session.declare_publisher(
            beat_key(lk, name, self._zid), congestion_control=zenoh.CongestionControl.DROP
        )
        self._token = liveliness.declare_token(
            member_token_key(lk, name, self._zid, self._fingerprint)
        )
        self._beat_due = True  # the others count this member from its first heartbeat
        # The callbacks run on Zenoh's own threads (each is short and never blocks): no
        # thread of their own whose backlog, under a flood of tokens, would grow without
        # bound and hold up the session's close.
        self._declared.append(
            self._session.declare_subscriber(beats_key(lk, name), _direct(self._on_beat))
        )
        watches = [(members_key(lk, name), self._on_member)]
        watches += [(source.watch, self._camera_callback(source)) for source in self._sources]
        for key, callback in watches:
            self._declared.append(
                liveliness.declare_subscriber(key, _direct(callback), history=True)
            )
        # the subscribers' history arrives in its own time: ask, and wait for the answers,
        # before taking anything (taking every stream for a moment would answer twice)
        self._discover(liveliness, watches)
        with self._lock:
            self._watched = None
        self._wait_for_beats()
        self._refuse_disagreeing()
        self._changed.set()
        self._thread.start()

    def _discover(self, liveliness: Any, watches: list[tuple[str, Callable[..., None]]]) -> None:
        """Ask who is there now, and wait for every answer (or the timeout). The answers go
        to a callback, not a channel: a full channel would stall Zenoh's runtime until this
        thread drains it, and with it every other thread's put."""
        finished: list[threading.Event] = []
        for key, callback in watches:
            done = threading.Event()
            finished.append(done)

            def on_reply(reply: zenoh.Reply, callback: Callable[..., None] = callback) -> None:
                if reply.ok is not None:
                    callback(reply.ok, answer=True)

            liveliness.get(
                key,
                zenoh.handlers.Callback(on_reply, done.set),
                timeout=self._discovery_timeout_s,
            )
        deadline = time.monotonic() + self._discovery_timeout_s + 1.0
        for done in finished:
            done.wait(max(0.0, deadline - time.monotonic()))

    def _wait_for_beats(self) -> None:
        """Wait (a few heartbeat periods at most) for a heartbeat of every member found."""
        deadline = time.monotonic() + 4 * BEAT_PERIOD_S
        while not self._stop.is_set():
            with self._lock:
                waiting = [m for m in self._members.values() if m.beat < 0]
                self._beaten.clear()
            left = deadline - time.monotonic()
            if not waiting or left <= 0:
                return
            self._beaten.wait(left)

    def _refuse_disagreeing(self) -> None:
        """Refuse to join where a live member serves with other settings."""
        now = time.monotonic()
        with self._lock:
            others = [
                (zid, differing(self._fingerprint, m.fingerprint))
                for zid, m in self._members.items()
                if now - m.beat <= self._silent_after_s
            ]
        for zid, settings in others:
            if settings:
                self.close()
                msg = (
                    f"share_group {self.name!r}: member {zid} serves with another "
                    f"{', '.join(settings)}: every instance of a group needs the same "
                    f"{', '.join(GROUP_SETTINGS)}"
                )
                raise SettingsError(msg)

    def close(self) -> None:
        """Release every stream, then leave the group (undeclare the token and watchers)."""
        self._stop.set()
        self._changed.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        for key in sorted(self._held):
            self._release(key)
        self._held = frozenset()
        for entity in [self._token, self._beat_pub, *reversed(self._declared)]:
            if entity is None:
                continue
            try:
                entity.undeclare()
            except zenoh.ZError as err:  # the session is already closed
                log.debug("event=undeclare_failed %s", kv(error=err))
        self._token = self._beat_pub = None
        self._declared.clear()

    # -- the heartbeat, driven by the service's worker loop ----------------------------------

    def beat(self) -> None:
        """Put this member's heartbeat when it is due (cheap otherwise). Called by every
        worker between frames and on each idle poll: it stops when they stop."""
        now = time.monotonic()
        publisher = self._beat_pub
        if publisher is None or (now < self._next_beat and not self._beat_due):
            return
        self._next_beat, self._beat_due = now + BEAT_PERIOD_S, False
        try:
            publisher.put(b"")
        except zenoh.ZError as err:  # the session closes
            self._ignore(AnnouncementError("beat_failed", str(err)))

    # -- Zenoh callbacks: update the sets, never block, never raise ---------------------------

    def _on_member(self, sample: zenoh.Sample, *, answer: bool = False) -> None:
        if self._stop.is_set():
            return
        key = str(sample.key_expr)
        present = sample.kind == zenoh.SampleKind.PUT
        if not self._fresh(key, present=present, answer=answer):
            return
        try:
            zid, fingerprint = member_of(key, self._liveliness_key, self.name)
        except AnnouncementError as err:
            if present:
                self._ignore(err, key)
            else:
                self._forget_ignored(key)
            return
        if zid == self._zid:
            return
        with self._lock:
            if not present:
                known = self._members.get(zid)
                if known is not None and known.fingerprint == fingerprint:
                    del self._members[zid]
                    self._changed.set()
                return
            known = self._members.get(zid)
            if known is not None and known.fingerprint == fingerprint:
                return  # seen already (a query's answer after the subscriber's sample)
            if known is None and len(self._members) >= MAX_MEMBERS:
                # room for a newcomer at the cost of the member silent the longest (bare
                # tokens never beat: a flood of them cannot shut real members out)
                self._ignored["too_many_members"] += 1
                victim = min(self._members, key=lambda z: self._members[z].heard)
                if time.monotonic() - self._members[victim].heard <= self._silent_after_s:
                    return
                del self._members[victim]
            self._members[zid] = _Member(fingerprint)
            self._beat_due = True  # the newcomer waits for our heartbeat before it takes
        self._log_disagreeing(zid, fingerprint)

    def _on_beat(self, sample: zenoh.Sample) -> None:
        try:
            zid = beat_of(str(sample.key_expr), self._liveliness_key, self.name)
        except AnnouncementError as err:
            self._ignore(err)
            return
        now = time.monotonic()
        with self._lock:
            member = self._members.get(zid)
            if member is None:
                return  # a heartbeat without a token (yet): the token comes first
            if now - member.beat > self._silent_after_s:
                self._changed.set()  # a newcomer, or a silent member back
                self._beaten.set()
            member.beat = now

    def _camera_callback(self, source: CameraSource) -> Callable[..., None]:
        def on_camera(sample: zenoh.Sample, *, answer: bool = False) -> None:
            if self._stop.is_set():  # a backlog left at close costs nothing
                return
            token = str(sample.key_expr)
            present = sample.kind == zenoh.SampleKind.PUT
            if not self._fresh(token, present=present, answer=answer):
                return
            try:
                read = source.read(token)
                if read is None:
                    return
                key, name = read
                with self._lock:
                    if present:
                        changed = self._streams.add(key, name, token)
                    else:
                        changed = self._streams.remove(token)
                if changed:
                    self._changed.set()
            except AnnouncementError as err:
                if present:
                    self._ignore(err, token)
                else:  # a key ignored when it came is ignored when it goes too
                    self._forget_ignored(token)

        return on_camera

    def _fresh(self, key: str, *, present: bool, answer: bool) -> bool:
        """While joining: whether a sample on ``key`` is news. The subscribers' history and
        the joining query report the same tokens; an ``answer`` may also be older than what a
        subscriber said since (a member that died meanwhile): it never overrides it."""
        with self._lock:
            watched = self._watched
            if watched is None:
                return True
            if watched.get(key) == present or (answer and key in watched):
                return False
            if len(watched) < 2 * MAX_ANNOUNCED:
                watched[key] = present
            return True

    def _ignore(self, err: AnnouncementError, token: str | None = None) -> None:
        """Count an ignored token by reason (once while it lives: ``token`` given), log it at
        a limited rate."""
        with self._lock:
            if token is not None:
                if token in self._ignored_tokens:
                    return
                if len(self._ignored_tokens) < MAX_ANNOUNCED:
                    self._ignored_tokens.add(token)
            self._ignored[err.reason] += 1
        self._log(
            logging.WARNING,
            f"group:{err.reason}",
            "announcement_ignored",
            group=self.name,
            reason=err.reason,
            key=err.key[:120],
        )

    def _forget_ignored(self, token: str) -> None:
        with self._lock:
            self._ignored_tokens.discard(token)

    def _log_disagreeing(self, zid: str, fingerprint: str) -> None:
        settings = differing(self._fingerprint, fingerprint)
        if not settings:
            return
        self._log(
            logging.WARNING,
            f"group:disagreeing:{zid}",
            "member_disagrees",
            group=self.name,
            member=zid,
            differs=",".join(settings),
            detail="left out of the assignment: every member needs the same "
            + ", ".join(GROUP_SETTINGS),
        )

    # -- the group's thread ------------------------------------------------------------------

    def _apply_loop(self) -> None:
        computed: tuple[frozenset[str], frozenset[str]] | None = None
        wanted: frozenset[str] = frozenset()
        while not self._stop.is_set():
            self._changed.wait(CHECK_S)
            if self._stop.is_set():
                return
            self._changed.clear()
            live, streams = self._sets()
            if (live, streams) != computed:
                computed = (live, streams)
                wanted = held_by(assign(streams, live, capacity=self._capacity), self._zid)
            if wanted != self._held:
                self._apply(wanted, members=len(live), streams=len(streams))

    def _sets(self) -> tuple[frozenset[str], frozenset[str]]:
        """The live agreeing members (this one included) and the live streams."""
        now = time.monotonic()
        with self._lock:
            live = frozenset(
                zid
                for zid, m in self._members.items()
                if now - m.beat <= self._silent_after_s
                and not differing(self._fingerprint, m.fingerprint)
            )
            streams = self._streams.keys()
        live |= {self._zid}
        self._evictions += len(self._live - live - self._gone(live))
        self._live = live
        return live, streams

    def _gone(self, live: frozenset[str]) -> set[str]:
        """Of the members live before and not now, those whose token is gone (not evicted)."""
        with self._lock:
            return {zid for zid in self._live - live if zid not in self._members}

    def _apply(self, wanted: frozenset[str], *, members: int, streams: int) -> None:
        # release first: a stream is never held twice by this instance's own doing
        released = self._held - wanted
        for key in sorted(released):
            self._release(key)
        held = self._held - released
        taken: list[str] = []
        for key in sorted(wanted - held):
            if self._stop.is_set():
                break
            try:
                self._take(key)
            except PerceptionError as err:  # Zenoh refused: tried again at the next check
                self._ignore(AnnouncementError("take_failed", f"{key}: {err}"))
                continue
            taken.append(key)
        self._held = held | frozenset(taken)
        self._changes += 1
        log.info(
            "event=group_changed %s",
            kv(
                group=self.name,
                members=members,
                streams=streams,
                held=len(self._held),
                taken=",".join(taken[:16]),
                released=",".join(sorted(released)[:16]),
            ),
        )

    # -- observability -----------------------------------------------------------------------

    @property
    def held(self) -> frozenset[str]:
        """The streams this instance holds now."""
        return self._held

    def status(self) -> dict[str, Any]:
        """JSON-ready: the group, its live members, the silent and disagreeing ones, the
        number of live streams, what is held and the tokens ignored by reason."""
        now = time.monotonic()
        with self._lock:
            members = dict(self._members)
            streams = len(self._streams)
            ignored = dict(self._ignored)
        silent = [z for z, m in members.items() if now - m.beat > self._silent_after_s]
        disagreeing = {
            zid: settings
            for zid, m in members.items()
            if (settings := differing(self._fingerprint, m.fingerprint))
        }
        return {
            "name": self.name,
            "fingerprint": self._fingerprint,
            "members": sorted(self._live),
            "silent": sorted(silent),
            "disagreeing": disagreeing,
            "evictions": self._evictions,
            "streams": streams,
            "held": sorted(self._held),
            "changes": self._changes,
            "ignored": ignored,
            "thread_alive": self._thread.is_alive(),
        }
