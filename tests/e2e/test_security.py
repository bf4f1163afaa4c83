"""The secured deployment profile (config/secure/) end to end, with in-process Zenoh sessions.

A router session loads config/secure/router.json5 (mutual TLS, access control by certificate
common name) or config/secure/usrpwd/router.json5 (TLS + user/password, access control by user
name); client sessions load the role configs next to it. The configs are used as shipped except
for certificate/secret paths, the port and the passwords, which are rewritten at run time. The
certificates are generated at run time by tests/certs.py.

Absence checks ("the spoofed sample never arrives") need a bounded wait: each such test first
waits for the legitimate samples (the positive control, sent after the spoofed ones), then
gives the spoofed ones `_ABSENCE_WINDOW` more seconds.
"""

from __future__ import annotations

import json
import queue
import secrets
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, cast

import json5
import numpy as np
import pytest
import zenoh

from tests.certs import ROGUE, STRANGER, Pki, make_pki
from tests.helpers import (
    REPO,
    Collector,
    Received,
    free_port,
    open_session,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from zenoh_perception.camera.shm import announce
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.service.ros_transport import RMW_ZENOH
from zenoh_perception.settings import load_settings
from zenoh_perception.wire.compressed import encode_compressed_frame
from zenoh_perception.wire.frames import RawFrameMeta, decode_raw_frame, encode_image_cdr
from zenoh_perception.wire.messages import (
    APRILTAG_DETECTION_ARRAY_TYPE as DETECTIONS_TYPE,
)
from zenoh_perception.wire.messages import COMPRESSED_IMAGE_TYPE as COMPRESSED_TYPE
from zenoh_perception.wire.messages import TF_MESSAGE_TYPE as TF_TYPE
from zenoh_perception.wire.messages import TYPESTORE, make_typestore
from zenoh_perception.wire.records import TagCodec, decode_record
from zenoh_perception.wire.rmw_zenoh import (
    ANY_HASH,
    PUBLISHER,
    SUBSCRIPTION,
    Attachment,
    NodeInfo,
    fully_qualified,
    gid_of,
    parse_token,
    topic_key,
    type_hash,
)
from zenoh_perception.wire.rmw_zenoh import Token as RmwToken
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction, ros_topic
from zenoh_perception_bench.scene import render_markers

_CONFIG_DIR = REPO / "config" / "secure"
_PROFILE_DIRS = {"mtls": _CONFIG_DIR, "usrpwd": _CONFIG_DIR / "usrpwd"}
_CLIENT_ROLES = ("camera", "perception", "consumer")

_FRAMES = "zed/left/image"
_TAG = "tag"
_TAGS_RECORD = "perception/tags"
_STATUS = "perception/status"
_ALIVE = "perception/alive"

_DELIVERY_TIMEOUT = 5.0
"""Upper bound for anything expected to arrive (loopback: it normally takes milliseconds)."""
_ABSENCE_WINDOW = 1.0
"""Extra time given to a sample that must NOT arrive, after the positive control arrived."""


def _rewrite_paths(node: Any, prefixes: dict[str, Path]) -> Any:
    """Replace relative placeholder paths such as "certs/ca.pem" by real files."""
    if isinstance(node, dict):
        return {key: _rewrite_paths(value, prefixes) for key, value in node.items()}
    if isinstance(node, list):
        return [_rewrite_paths(value, prefixes) for value in node]
    if isinstance(node, str):
        for prefix, directory in prefixes.items():
            if node.startswith(prefix):
                return str(directory / node.removeprefix(prefix))
    return node


class _Deployment:
    """One secured router plus the role clients of a profile; closes every session it opened."""

    def __init__(self, profile: str, pki: Pki, tmp_path: Path) -> None:
        self.profile = profile
        self.pki = pki
        self.port = free_port()
        self._dir = _PROFILE_DIRS[profile]
        self._sessions: list[zenoh.Session] = []
        self.passwords = {role: secrets.token_urlsafe(16) for role in _CLIENT_ROLES}
        secrets_dir = tmp_path / "secrets"
        secrets_dir.mkdir()
        (secrets_dir / "users.txt").write_text(
            "".join(f"{user}:{password}\n" for user, password in self.passwords.items()),
            encoding="utf-8",
        )
        self._prefixes = {"certs/": pki.ca.parent, "secrets/": secrets_dir}

    def config(self, name: str) -> dict[str, Any]:
        """`name`.json5 of the profile with paths and port rewritten (passwords untouched)."""
        with (self._dir / f"{name}.json5").open(encoding="utf-8") as handle:
            raw: dict[str, Any] = json5.load(handle)
        config: dict[str, Any] = _rewrite_paths(raw, self._prefixes)
        endpoint = [f"tls/127.0.0.1:{self.port}"]
        if name == "router":
            config["listen"]["endpoints"] = endpoint
        else:
            config["connect"]["endpoints"] = endpoint
            if self.profile == "usrpwd":
                config["transport"]["auth"]["usrpwd"]["password"] = self.passwords[name]
        return config

    def open(self, config: dict[str, Any]) -> zenoh.Session:
        session = zenoh.open(zenoh.Config.from_json5(json.dumps(config)))
        self._sessions.append(session)
        return session

    def client(self, role: str) -> zenoh.Session:
        return self.open(self.config(role))

    def close(self) -> None:
        for session in reversed(self._sessions):
            session.close()
        self._sessions.clear()


def _sample(inbox: Collector) -> tuple[str, bytes]:
    """Key and payload of the next sample (queue.Empty after `_DELIVERY_TIMEOUT`)."""
    received = inbox.get(timeout=_DELIVERY_TIMEOUT)
    return received.key, received.payload


def _late_arrivals(*inboxes: Collector) -> list[tuple[str, bytes]]:
    """What the inboxes receive in the next `_ABSENCE_WINDOW` seconds (one shared wait)."""
    first, *others = inboxes
    late: list[tuple[str, bytes]] = []
    try:
        while True:  # until a whole window passes with nothing new
            received = first.get(timeout=_ABSENCE_WINDOW)
            late.append((received.key, received.payload))
    except queue.Empty:
        pass
    late += [(r.key, r.payload) for inbox in others for r in inbox.drain()]
    return late


def _publisher_seeing_subscriber(session: zenoh.Session, key_expr: str) -> zenoh.Publisher:
    """A publisher on `key_expr`, once the router has told it that a subscriber exists.

    This proves the router knows the subscriber, so a put that does not arrive was dropped by
    the access control, not lost to declaration propagation. It blocks rather than drops when
    its queue is full (Zenoh's default drops a large frame that cannot be queued within 1 ms,
    as happens on a busy machine), so no put is lost on the way out either.
    """
    publisher = session.declare_publisher(
        key_expr, congestion_control=zenoh.CongestionControl.BLOCK
    )
    wait_for_subscriber(publisher, timeout=_DELIVERY_TIMEOUT)
    return publisher


def _round_trip(session: zenoh.Session) -> None:
    """Return once the router has processed everything `session` sent before (FIFO link)."""
    list(session.get("perception/sync", timeout=_DELIVERY_TIMEOUT))


def _status_replies(session: zenoh.Session) -> list[bytes]:
    replies = session.get(_STATUS, timeout=_DELIVERY_TIMEOUT)
    return [reply.ok.payload.to_bytes() for reply in replies if reply.ok is not None]


def _alive_tokens(session: zenoh.Session) -> list[str]:
    replies = session.liveliness().get(f"{_ALIVE}/**", timeout=_DELIVERY_TIMEOUT)
    return sorted(str(reply.ok.key_expr) for reply in replies if reply.ok is not None)


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("certs"))


def _deployment(profile: str, pki: Pki, tmp_path: Path) -> Iterator[_Deployment]:
    deployment = _Deployment(profile, pki, tmp_path)
    try:
        deployment.open(deployment.config("router"))
        yield deployment
    finally:
        deployment.close()


@pytest.fixture(params=sorted(_PROFILE_DIRS))
def secured(request: pytest.FixtureRequest, pki: Pki, tmp_path: Path) -> Iterator[_Deployment]:
    """A running secured router, for each profile (mtls, usrpwd)."""
    yield from _deployment(request.param, pki, tmp_path)


@pytest.fixture
def mtls(pki: Pki, tmp_path: Path) -> Iterator[_Deployment]:
    """A running router of the mutual-TLS profile."""
    yield from _deployment("mtls", pki, tmp_path)


@pytest.fixture
def usrpwd(pki: Pki, tmp_path: Path) -> Iterator[_Deployment]:
    """A running router of the user/password profile."""
    yield from _deployment("usrpwd", pki, tmp_path)


# Legitimate traffic goes through.


def test_camera_frames_reach_perception(secured: _Deployment) -> None:
    frames = Collector(secured.client("perception"), _FRAMES)
    camera = _publisher_seeing_subscriber(secured.client("camera"), _FRAMES)

    camera.put(b"frame-1")

    assert _sample(frames) == (_FRAMES, b"frame-1")


def test_perception_outputs_reach_consumer(secured: _Deployment) -> None:
    consumer = secured.client("consumer")
    tags = Collector(consumer, _TAG)
    records = Collector(consumer, "perception/**")
    perception = secured.client("perception")
    tag = _publisher_seeing_subscriber(perception, _TAG)
    record = _publisher_seeing_subscriber(perception, _TAGS_RECORD)

    tag.put(b"tag-1")
    record.put(b"record-1")

    assert _sample(tags) == (_TAG, b"tag-1")
    assert _sample(records) == (_TAGS_RECORD, b"record-1")


def test_consumer_reads_perception_status_and_liveliness(secured: _Deployment) -> None:
    perception = secured.client("perception")
    perception.declare_queryable(_STATUS, lambda query: query.reply(_STATUS, b"ok"))
    token = perception.liveliness().declare_token(f"{_ALIVE}/service")  # alive while referenced
    _round_trip(perception)
    consumer = secured.client("consumer")

    assert _status_replies(consumer) == [b"ok"]
    assert _alive_tokens(consumer) == [f"{_ALIVE}/service"]
    token.undeclare()


# Authenticated roles cannot publish outside their keys.


def test_roles_cannot_publish_outside_their_keys(secured: _Deployment) -> None:
    """Each spoofing publisher first sees a matching subscriber, and its put raises nothing:
    the router drops it without telling the sender (docs/security.md, a denied key is
    silent)."""
    frames = Collector(secured.client("perception"), _FRAMES)
    navigation = secured.client("consumer")
    tags = Collector(navigation, _TAG)
    records = Collector(navigation, "perception/**")
    intruder = secured.client("consumer")  # authenticated, but only allowed to read
    camera = secured.client("camera")
    perception = secured.client("perception")
    spoofs = [
        (intruder, _FRAMES),
        (intruder, _TAG),
        (intruder, _TAGS_RECORD),
        (camera, _TAG),  # the camera may publish frames only
        (camera, _TAGS_RECORD),
        (perception, _FRAMES),  # the service may not inject frames
    ]
    for session, key in spoofs:
        _publisher_seeing_subscriber(session, key).put(b"spoof")

    # Positive control, sent after the spoofs over the same router.
    _publisher_seeing_subscriber(camera, _FRAMES).put(b"frame")
    _publisher_seeing_subscriber(perception, _TAG).put(b"tag")
    _publisher_seeing_subscriber(perception, _TAGS_RECORD).put(b"record")
    first = [_sample(frames), _sample(tags), _sample(records)]

    assert first == [(_FRAMES, b"frame"), (_TAG, b"tag"), (_TAGS_RECORD, b"record")]
    assert _late_arrivals(frames, tags, records) == []


def test_consumer_cannot_impersonate_perception_status_or_liveliness(
    secured: _Deployment,
) -> None:
    intruder = secured.client("consumer")
    intruder.declare_queryable(_STATUS, lambda query: query.reply(_STATUS, b"spoof"))
    fake_token = intruder.liveliness().declare_token(f"{_ALIVE}/fake")
    _round_trip(intruder)  # the router has seen (and refused) the intruder's declarations
    perception = secured.client("perception")
    perception.declare_queryable(_STATUS, lambda query: query.reply(_STATUS, b"ok"))
    token = perception.liveliness().declare_token(f"{_ALIVE}/service")  # alive while referenced
    _round_trip(perception)
    navigation = secured.client("consumer")

    assert _status_replies(navigation) == [b"ok"]
    assert _alive_tokens(navigation) == [f"{_ALIVE}/service"]
    token.undeclare()
    fake_token.undeclare()


# Sessions without valid credentials never get a link (mutual TLS profile).


def test_certificate_from_another_ca_is_refused(mtls: _Deployment) -> None:
    rogue = mtls.config("camera")  # claims CN=camera, but signed by the rogue CA
    tls = rogue["transport"]["link"]["tls"]
    tls["connect_certificate"] = str(mtls.pki[ROGUE].cert)
    tls["connect_private_key"] = str(mtls.pki[ROGUE].key)
    frames = Collector(mtls.client("perception"), _FRAMES)

    with pytest.raises(zenoh.ZError):
        mtls.open(rogue)

    _publisher_seeing_subscriber(mtls.client("camera"), _FRAMES).put(b"frame")
    assert _sample(frames) == (_FRAMES, b"frame")


def test_client_without_certificate_is_refused(mtls: _Deployment) -> None:
    anonymous = mtls.config("camera")
    tls = anonymous["transport"]["link"]["tls"]
    del tls["connect_certificate"], tls["connect_private_key"]
    tls["enable_mtls"] = False  # plain TLS: verifies the router, presents no certificate
    frames = Collector(mtls.client("perception"), _FRAMES)

    with pytest.raises(zenoh.ZError):
        mtls.open(anonymous)

    _publisher_seeing_subscriber(mtls.client("camera"), _FRAMES).put(b"frame")
    assert _sample(frames) == (_FRAMES, b"frame")


def test_camera_refuses_an_impostor_router(mtls: _Deployment) -> None:
    impostor = mtls.config("router")
    impostor["listen"]["endpoints"] = [f"tls/127.0.0.1:{free_port()}"]
    tls = impostor["transport"]["link"]["tls"]
    tls["listen_certificate"] = str(mtls.pki[ROGUE].cert)
    tls["listen_private_key"] = str(mtls.pki[ROGUE].key)
    tls["root_ca_certificate"] = str(mtls.pki.rogue_ca)
    tls["enable_mtls"] = False  # the impostor would accept anyone: only the camera can refuse
    mtls.open(impostor)
    camera = mtls.config("camera")

    mtls.open(camera)  # positive control: the real router is accepted
    camera["connect"]["endpoints"] = impostor["listen"]["endpoints"]
    with pytest.raises(zenoh.ZError):
        mtls.open(camera)


def test_valid_certificate_with_unlisted_name_can_neither_publish_nor_read(
    mtls: _Deployment,
) -> None:
    stranger_config = mtls.config("consumer")
    tls = stranger_config["transport"]["link"]["tls"]
    tls["connect_certificate"] = str(mtls.pki[STRANGER].cert)
    tls["connect_private_key"] = str(mtls.pki[STRANGER].key)
    stranger = mtls.open(stranger_config)  # the CA vouches for it: the link comes up
    stranger_tags = Collector(stranger, _TAG)
    frames = Collector(mtls.client("perception"), _FRAMES)
    tags = Collector(mtls.client("consumer"), _TAG)
    camera = _publisher_seeing_subscriber(mtls.client("camera"), _FRAMES)
    tag = _publisher_seeing_subscriber(mtls.client("perception"), _TAG)

    stranger.put(_FRAMES, b"spoof")  # the router knows the frames subscriber by now
    camera.put(b"frame")
    tag.put(b"tag")

    assert [_sample(frames), _sample(tags)] == [(_FRAMES, b"frame"), (_TAG, b"tag")]
    assert _late_arrivals(frames, stranger_tags) == []


# Sessions without valid credentials never get a session (user/password profile).


@pytest.mark.parametrize(
    ("user", "password"),
    [("camera", "wrong-password"), ("intruder", "any"), (None, None)],
    ids=["wrong-password", "unknown-user", "no-login"],
)
def test_bad_login_is_refused(usrpwd: _Deployment, user: str | None, password: str | None) -> None:
    config = usrpwd.config("camera")
    if user is None:
        del config["transport"]["auth"]
    else:
        config["transport"]["auth"]["usrpwd"] = {"user": user, "password": password}
    frames = Collector(usrpwd.client("perception"), _FRAMES)

    with pytest.raises(zenoh.ZError):
        usrpwd.open(config)

    _publisher_seeing_subscriber(usrpwd.client("camera"), _FRAMES).put(b"frame")
    assert _sample(frames) == (_FRAMES, b"frame")


# The router's rules cover every key the service uses, in both ROS transports.
#
# The service declares its keys on a recording session (the real PerceptionService, settings
# from config/perception.toml), and a model of the router's decision (a rule applies to a
# message when the rule's key expression includes the message's key; a deny rule wins; else
# an allow rule admits, else the default denies) checks each against the shipped rules. The
# end-to-end tests below hold the model to the real router.

_PUBLISH, _SUBSCRIBE, _QUERYABLE = "put", "declare_subscriber", "declare_queryable"
_TOKEN, _TOKEN_WATCH = "liveliness_token", "declare_liveliness_subscriber"
_TRANSPORTS = ("bridge", "rmw_zenoh")
#: Every setting on: the camera's CameraInfo too (off by default).
_ALL_KEYS = {"camera_info_key": "zed/left/camera_info"}


_SESSION_DECLARATIONS = {
    "declare_publisher": _PUBLISH,
    "declare_subscriber": _SUBSCRIBE,
    "declare_queryable": _QUERYABLE,
}
_LIVELINESS_DECLARATIONS = {"declare_token": _TOKEN, "declare_subscriber": _TOKEN_WATCH}


class _Recording:
    """A Zenoh session (or its liveliness) that notes each declaration (message, key) in
    ``used``, then makes it."""

    def __init__(self, target: Any, messages: dict[str, str], used: list[tuple[str, str]]) -> None:
        self._target = target
        self._messages = messages
        self.used = used

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._target, name)
        if name == "liveliness":
            return lambda: _Recording(attr(), _LIVELINESS_DECLARATIONS, self.used)
        message = self._messages.get(name)
        if message is None:
            return attr

        def declare(key: object, *args: Any, **kwargs: Any) -> Any:
            self.used.append((message, str(key)))
            return attr(key, *args, **kwargs)

        return declare


def _service_keys(transport: str) -> list[tuple[str, str]]:
    """What the real service declares with every output on, in ``transport``."""
    overrides = {**_ALL_KEYS, "ros_transport": transport, "frame_deadline_ms": 0}
    settings = load_settings(REPO / "config" / "perception.toml", overrides)
    with open_session() as session:
        used: list[tuple[str, str]] = []
        recording = _Recording(session, _SESSION_DECLARATIONS, used)
        with PerceptionService(cast(zenoh.Session, recording), settings):
            pass
    return used


@dataclass(frozen=True)
class _Acl:
    """The router's access control decision, from its ``access_control`` section."""

    config: dict[str, Any]

    def _rules(self, subject: str, flow: str, message: str) -> list[dict[str, Any]]:
        names = {
            rule
            for policy in self.config["policies"]
            if subject in policy["subjects"]
            for rule in policy["rules"]
        }
        return [
            rule
            for rule in self.config["rules"]
            if rule["id"] in names and flow in rule["flows"] and message in rule["messages"]
        ]

    def permits(self, subject: str, message: str, key: str, *, flow: str = "ingress") -> bool:
        rules = self._rules(subject, flow, message)

        def applies(permission: str) -> bool:
            return any(
                zenoh.KeyExpr(expr).includes(zenoh.KeyExpr(key))
                for rule in rules
                if rule["permission"] == permission
                for expr in rule["key_exprs"]
            )

        if applies("deny"):
            return False
        return self.config["default_permission"] == "allow" or applies("allow")


def _acl(profile: str) -> _Acl:
    with (_PROFILE_DIRS[profile] / "router.json5").open(encoding="utf-8") as handle:
        return _Acl(json5.load(handle)["access_control"])


def _ros_peer_tokens(transport: str) -> dict[str, list[str]]:
    """The rmw_zenoh tokens of the camera node (publishing what the service reads) and of a
    consumer node (subscribing to what it publishes)."""
    if transport != RMW_ZENOH:
        return {"camera": [], "consumer": []}
    peer = _Peer(transport, _ALL_KEYS)
    tokens: dict[str, list[str]] = {}
    for role, name, direction, kind in [
        ("camera", "zed_camera", Direction.SUBSCRIBE, PUBLISHER),
        ("consumer", "navigation", Direction.PUBLISH, SUBSCRIPTION),
    ]:
        node = NodeInfo(0, "0123456789abcdef0123456789abcdef", name)
        tokens[role] = [node.node_token()] + [
            peer.token(node, entity_id, kind, topic.role)
            for entity_id, topic in enumerate(ROS_TOPICS, start=1)
            if topic.direction is direction
        ]
    return tokens


@pytest.fixture(scope="module", params=_TRANSPORTS)
def service_keys(request: pytest.FixtureRequest) -> tuple[str, list[tuple[str, str]]]:
    return request.param, _service_keys(request.param)


def test_the_service_declares_every_topic_of_the_table(
    service_keys: tuple[str, list[tuple[str, str]]],
) -> None:
    """The recording sees every ROS topic and the rest (the checks below are not vacuous)."""
    transport, used = service_keys
    peer = _Peer(transport, _ALL_KEYS)
    expected = {peer.key(topic.role, any_hash=topic.any_hash) for topic in ROS_TOPICS}
    assert expected <= {key for message, key in used if message in (_PUBLISH, _SUBSCRIBE)}
    assert {_QUERYABLE, _TOKEN, _TOKEN_WATCH} <= {message for message, _ in used}


@pytest.mark.parametrize("profile", sorted(_PROFILE_DIRS))
def test_the_service_may_declare_and_publish_every_key_it_uses(
    profile: str, service_keys: tuple[str, list[tuple[str, str]]]
) -> None:
    acl = _acl(profile)
    _, used = service_keys
    denied = [(m, key) for m, key in used if not acl.permits("perception", m, key)]
    assert denied == []
    replies = [key for m, key in used if m == _QUERYABLE]
    assert [key for key in replies if not acl.permits("perception", "reply", key)] == []


@pytest.mark.parametrize("profile", sorted(_PROFILE_DIRS))
def test_what_the_service_publishes_reaches_every_role_and_comes_from_it_alone(
    profile: str, service_keys: tuple[str, list[tuple[str, str]]]
) -> None:
    acl = _acl(profile)
    _, used = service_keys
    outputs = [key for m, key in used if m == _PUBLISH]
    served = [key for m, key in used if m == _QUERYABLE]
    tokens = [key for m, key in used if m == _TOKEN]
    for role in ("camera", "perception", "consumer"):
        for key in outputs:
            assert acl.permits(role, _SUBSCRIBE, key), (role, key)
            assert acl.permits(role, "put", key, flow="egress"), (role, key)
        for key in served:
            assert acl.permits(role, "query", key), (role, key)
            assert acl.permits(role, "reply", key, flow="egress"), (role, key)
        for key in tokens:
            assert acl.permits(role, _TOKEN_WATCH, key), (role, key)
            assert acl.permits(role, "liveliness_query", key), (role, key)
            assert acl.permits(role, _TOKEN, key, flow="egress"), (role, key)
    for impostor in ("camera", "consumer", STRANGER):
        assert [key for key in outputs if acl.permits(impostor, "put", key)] == []
        assert [key for key in served if acl.permits(impostor, _QUERYABLE, key)] == []
        assert [key for key in served if acl.permits(impostor, "reply", key)] == []
        assert [key for key in tokens if acl.permits(impostor, _TOKEN, key)] == []


@pytest.mark.parametrize("profile", sorted(_PROFILE_DIRS))
def test_what_the_service_reads_comes_from_the_camera_alone(
    profile: str, service_keys: tuple[str, list[tuple[str, str]]]
) -> None:
    acl = _acl(profile)
    transport, used = service_keys
    inputs = [key for m, key in used if m == _SUBSCRIBE]
    assert [key for key in inputs if not acl.permits("camera", "put", key)] == []
    assert [key for key in inputs if not acl.permits("perception", "put", key, flow="egress")] == []
    for impostor in ("perception", "consumer", STRANGER):
        assert [key for key in inputs if acl.permits(impostor, "put", key)] == []
    watched = [key for m, key in used if m == _TOKEN_WATCH]
    assert all(acl.permits("perception", _TOKEN, key, flow="egress") for key in watched)
    # the ROS nodes on each side of the service may say so on an rmw_zenoh graph
    peer_tokens = _ros_peer_tokens(transport)
    for role, tokens in peer_tokens.items():
        assert [key for key in tokens if not acl.permits(role, _TOKEN, key)] == []
    impostor_tokens = peer_tokens["camera"][1:]  # the camera's publishers: the camera's alone
    assert [key for key in impostor_tokens if acl.permits("consumer", _TOKEN, key)] == []


# The real service behind the secured router.


_W, _H = 640, 480
#: Intrinsics and a tag size: each tag then has a pose, so the service publishes ``tf`` too.
_POSE_ARGS = (
    "--camera-fx", "500", "--camera-fy", "500", "--camera-cx", "320", "--camera-cy", "240",
    "--tag-size-m", "0.1",
)  # fmt: skip
_OUTPUTS = ("tag", "detections", "tf", "debug_image")
_SPOOF = b"spoof"


def _marker_image(tag_id: int) -> np.ndarray:
    corners = np.array([[200.0, 140.0], [360.0, 140.0], [360.0, 300.0], [200.0, 300.0]])
    return render_markers(_W, _H, [(tag_id, corners)])


class _Peer:
    """A ROS peer of the service in one transport: the keys of its topics (rmw_zenoh's
    ``<domain>/<topic>/<type>/<hash>``, or the plain keys the bridge maps) and the frames a
    camera publishes on them."""

    def __init__(self, transport: str, overrides: Mapping[str, object] | None = None) -> None:
        self.rmw_zenoh = transport == RMW_ZENOH
        self._settings = load_settings(REPO / "config" / "perception.toml", overrides)
        self._store = make_typestore(self._settings.ros.ros_package)
        self._seq = 0

    def key(self, role: str, *, any_hash: bool = False) -> str:
        """A topic's key; ``any_hash``: every version of its type (a subscription's)."""
        topic = ros_topic(role)
        plain = str(self._settings.topic_keys()[topic.key_setting])
        if not self.rmw_zenoh:
            return plain
        ros_type = topic.type_name(self._settings.ros.ros_package)
        hash_ = ANY_HASH if any_hash else type_hash(self._store, ros_type)
        return topic_key(0, fully_qualified("", plain), ros_type, hash_)

    def token(self, node: NodeInfo, entity_id: int, kind: str, role: str) -> str:
        topic = ros_topic(role)
        ros_type = topic.type_name(self._settings.ros.ros_package)
        fq_topic = fully_qualified("", str(self._settings.topic_keys()[topic.key_setting]))
        hash_ = type_hash(self._store, ros_type)
        return node.entity_token(entity_id, kind, fq_topic, ros_type, hash_=hash_, qos=topic.qos)

    def raw_frame(self, tag_id: int, gid: bytes) -> tuple[bytes, bytes | None]:
        """Payload and attachment of a raw frame showing ``tag_id``."""
        self._seq += 1
        image = _marker_image(tag_id)
        if not self.rmw_zenoh:
            return image.tobytes(), RawFrameMeta(_W, _H, seq=self._seq).to_msgpack()
        cdr = bytes(encode_image_cdr(image, "bgra8", stamp_ns=time.time_ns()))
        return cdr, Attachment(self._seq, time.time_ns(), gid).encode()

    def compressed_frame(self, tag_id: int, gid: bytes) -> tuple[bytes, bytes | None]:
        self._seq += 1
        frame = decode_raw_frame(_marker_image(tag_id).tobytes(), RawFrameMeta(_W, _H).to_msgpack())
        jpeg = bytes(encode_compressed_frame(frame, "jpeg", stamp_ns=1, frame_id="zed_left"))
        if not self.rmw_zenoh:
            return jpeg, None
        return jpeg, Attachment(self._seq, time.time_ns(), gid).encode()


def _cfg_args(deployment: _Deployment) -> list[str]:
    """--cfg flags pointing the shipped perception.json5 at the test's certificates (and,
    user/password profile, giving the password)."""
    tls = "transport/link/tls"
    overrides: dict[str, object] = {f"{tls}/root_ca_certificate": str(deployment.pki.ca)}
    if deployment.profile == "usrpwd":
        overrides["transport/auth/usrpwd/password"] = deployment.passwords["perception"]
    else:
        role = deployment.pki["perception"]
        overrides[f"{tls}/connect_certificate"] = str(role.cert)
        overrides[f"{tls}/connect_private_key"] = str(role.key)
    return [
        arg for key, value in overrides.items() for arg in ("--cfg", f"{key}:{json.dumps(value)}")
    ]


def _ros_graph(session: zenoh.Session) -> list[RmwToken]:
    replies = session.liveliness().get("@ros2_lv/0/**", timeout=_DELIVERY_TIMEOUT)
    return [parse_token(str(reply.ok.key_expr)) for reply in replies if reply.ok is not None]


def _sample_of(inbox: Collector) -> Received:
    """The next sample, from the service (a spoof that got through fails the test)."""
    received = inbox.get(timeout=30)
    assert received.payload != _SPOOF, f"a spoofed sample reached the consumer on {received.key}"
    return received


@pytest.mark.parametrize("transport", _TRANSPORTS)
def test_real_service_with_the_shipped_perception_config(
    secured: _Deployment, transport: str
) -> None:
    """`zenoh-perception run -c config/secure/perception.json5` (or usrpwd/) behind the
    secured router, in both ROS transports: raw and compressed frames are answered, and a
    consumer receives the tag, record, detections, transforms, debug image, status and
    liveliness; the same keys refuse an impostor (an authenticated consumer, or the camera,
    publishing or serving them, or feeding the service frames; on an rmw_zenoh graph,
    claiming the service's node).

    The shipped config is used as is; only the router endpoint (-e), the certificate paths and
    the password (--cfg) are overridden on the command line, as an operator would.
    """
    peer = _Peer(transport)
    consumer = secured.client("consumer")
    outputs = {role: Collector(consumer, peer.key(role, any_hash=True)) for role in _OUTPUTS}
    records = Collector(consumer, _TAGS_RECORD)
    camera = secured.client("camera")
    camera_node = NodeInfo(0, str(camera.zid()), "zed_camera")
    camera_tokens = [camera_node.node_token()] + [
        peer.token(camera_node, entity_id, PUBLISHER, role)
        for entity_id, role in enumerate(("camera", "compressed_camera"), start=1)
    ]
    kept = [camera.liveliness().declare_token(token) for token in camera_tokens]
    gid = gid_of(camera_tokens[1])

    with running_cli(
        "run", "-c", str(_PROFILE_DIRS[secured.profile] / "perception.json5"),
        "-e", f"tls/127.0.0.1:{secured.port}", *_cfg_args(secured),
        "--ros-transport", transport, "--stats-interval-s", "0", *_POSE_ARGS,
    ) as service:  # fmt: skip
        status = wait_for_status(consumer)  # the status queryable answers through the router
        raw = _publisher_seeing_subscriber(camera, peer.key("camera"))
        compressed = _publisher_seeing_subscriber(camera, peer.key("compressed_camera"))
        codec = TagCodec()

        payload, attachment = peer.raw_frame(7, gid)
        raw.put(payload, attachment=attachment)
        first = {role: _sample_of(outputs[role]) for role in _OUTPUTS}
        record = decode_record(_sample_of(records).payload)
        payload, attachment = peer.compressed_frame(9, gid)
        compressed.put(payload, attachment=attachment)
        answered = codec.decode(_sample_of(outputs["tag"]).payload).tag_id

        # Impostors: an authenticated consumer publishes on every output and feeds frames
        # (tag 13), serves the status and claims the service's liveliness (and ROS node);
        # the camera publishes a tag.
        intruder = secured.client("consumer")
        spoofed = [(intruder, first[role].key) for role in _OUTPUTS] + [
            (intruder, _TAGS_RECORD),
            (camera, first["tag"].key),
        ]
        for session, key in spoofed:
            _publisher_seeing_subscriber(session, key).put(_SPOOF)
        for key, (payload, attachment) in [
            (peer.key("camera"), peer.raw_frame(13, gid)),
            (peer.key("compressed_camera"), peer.compressed_frame(13, gid)),
        ]:
            _publisher_seeing_subscriber(intruder, key).put(payload, attachment=attachment)
        intruder.declare_queryable(_STATUS, lambda query: query.reply(_STATUS, _SPOOF))
        fake_tokens = [f"{_ALIVE}/fake"]
        if peer.rmw_zenoh:
            fake_node = NodeInfo(0, str(intruder.zid()), "zenoh_perception")
            fake_tokens += [fake_node.node_token(), peer.token(fake_node, 1, PUBLISHER, "tag")]
        kept += [intruder.liveliness().declare_token(token) for token in fake_tokens]
        _round_trip(intruder)  # the router has taken (and refused) all of it
        _round_trip(camera)

        # Positive control, after the spoofs: the camera's next frame is answered.
        payload, attachment = peer.raw_frame(7, gid)
        raw.put(payload, attachment=attachment)
        again = codec.decode(_sample_of(outputs["tag"]).payload).tag_id
        late = _late_arrivals(*outputs.values(), records)
        replies = _status_replies(consumer)
        tokens = _alive_tokens(consumer)
        graph = _ros_graph(consumer)
        assert service.poll() is None

    for token in kept:
        token.undeclare()
    assert codec.decode(first["tag"].payload).tag_id == 7
    assert record["selected"]["tag_id"] == 7
    detections: Any = TYPESTORE.deserialize_cdr(first["detections"].payload, DETECTIONS_TYPE)
    assert [d.id for d in detections.detections] == [7]
    transforms: Any = TYPESTORE.deserialize_cdr(first["tf"].payload, TF_TYPE)
    assert [t.child_frame_id for t in transforms.transforms] == ["tag_7"]
    image: Any = TYPESTORE.deserialize_cdr(first["debug_image"].payload, COMPRESSED_TYPE)
    assert image.format.startswith("jpeg")
    assert (answered, again) == (9, 7)
    assert [(key, payload) for key, payload in late if payload == _SPOOF] == []
    assert 13 not in [codec.decode(p).tag_id for k, p in late if k == first["tag"].key]
    assert [json.loads(reply)["frames"]["received"] for reply in replies] == [3]
    assert tokens == [f"{_ALIVE}/{status['zid']}"]
    if peer.rmw_zenoh:  # the camera's node and publishers are on the graph, no false service
        service_tokens = [t for t in graph if t.node_name == "zenoh_perception"]
        assert {t.session_id for t in service_tokens} == {status["zid"]}
        assert len(service_tokens) == 1 + len(ROS_TOPICS) - 1  # node + topics, CameraInfo off
        assert sum(t.node_name == "zed_camera" for t in graph) == len(camera_tokens)


def test_a_share_group_behind_the_secured_router(secured: _Deployment) -> None:
    """Two instances in a share group behind the secured router: the camera's announcement
    reaches them, one of them answers each frame, once; a consumer's forged member token and
    camera announcement are dropped by the router (the group never sees them)."""
    camera = secured.client("camera")
    consumer = secured.client("consumer")
    records = Collector(consumer, _TAGS_RECORD)
    announced = announce(camera, _FRAMES)
    flags = (
        "run", "-c", str(_PROFILE_DIRS[secured.profile] / "perception.json5"),
        "-e", f"tls/127.0.0.1:{secured.port}", *_cfg_args(secured),
        "--share-group", "rover", "--stats-interval-s", "0",
    )  # fmt: skip

    def groups() -> list[dict[str, Any]]:
        """Every instance's group status (each answers on the same key)."""
        replies = consumer.get(
            _STATUS,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=_DELIVERY_TIMEOUT,
        )
        found = [json.loads(r.ok.payload.to_bytes())["group"] for r in replies if r.ok is not None]
        return [g for g in found if g is not None]  # None: an instance still joining

    with running_cli(*flags), running_cli(*flags):
        wait_until(
            lambda: sorted(len(g["held"]) for g in groups() if len(g["members"]) == 2) == [0, 1],
            what="two members, one holding the camera",
        )
        fingerprint = groups()[0]["fingerprint"]
        intruder = secured.client("consumer")
        forged = [
            intruder.liveliness().declare_token(key)
            for key in (
                f"{_ALIVE}/group/rover/member/abcdef01/{fingerprint}",
                "@camera/zed/left/image/compressed",
            )
        ]
        _round_trip(intruder)  # the router has taken (and refused) both
        raw = _publisher_seeing_subscriber(camera, _FRAMES)
        meta = RawFrameMeta(_W, _H)
        for seq in range(5):
            frame = replace(meta, seq=seq).to_msgpack()
            raw.put(_marker_image(7).tobytes(), attachment=frame)
            assert decode_record(records.get(timeout=30).payload)["seq"] == seq
        late = _late_arrivals(records)
        after = groups()
        for token in [*forged, announced]:
            token.undeclare()
    assert late == []  # no frame answered twice
    assert [(g["streams"], g["silent"], g["ignored"]) for g in after] == [(1, [], {})] * 2
