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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import json5
import numpy as np
import pytest
import zenoh

from tests.certs import ROGUE, STRANGER, Pki, make_pki
from tests.helpers import (
    REPO,
    Collector,
    free_port,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
)
from zenoh_perception.scene import render_markers
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.records import TagCodec, decode_record

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


# The real service behind the secured router.


def test_real_service_with_the_shipped_perception_config(mtls: _Deployment) -> None:
    """`zenoh-perception run -c config/secure/perception.json5` talks only through the router.

    The shipped config is used as is; only the router endpoint (-e) and the certificate paths
    (--cfg) are overridden on the command line, as an operator would.
    """
    role = mtls.pki["perception"]
    tls = "transport/link/tls"
    overrides = {
        f"{tls}/root_ca_certificate": mtls.pki.ca,
        f"{tls}/connect_certificate": role.cert,
        f"{tls}/connect_private_key": role.key,
    }
    cfg_args = [
        arg
        for key, path in overrides.items()
        for arg in ("--cfg", f"{key}:{json.dumps(str(path))}")
    ]
    consumer = mtls.client("consumer")
    tags = Collector(consumer, _TAG)
    records = Collector(consumer, _TAGS_RECORD)
    side = 160.0
    corners = np.array([[200, 120], [200 + side, 120], [200 + side, 120 + side], [200, 120 + side]])
    image = render_markers(640, 480, [(7, corners)])

    with running_cli(
        "run", "-c", str(_CONFIG_DIR / "perception.json5"),
        "-e", f"tls/127.0.0.1:{mtls.port}", *cfg_args,
    ) as service:  # fmt: skip
        status = wait_for_status(consumer)  # the status queryable answers through the router
        tokens = _alive_tokens(consumer)
        camera = _publisher_seeing_subscriber(mtls.client("camera"), _FRAMES)
        camera.put(image.tobytes(), attachment=RawFrameMeta(640, 480, seq=1).to_msgpack())
        tag = TagCodec().decode(tags.get(timeout=30).payload)
        record = decode_record(records.get(timeout=_DELIVERY_TIMEOUT).payload)
        assert service.poll() is None

    assert tokens == [f"{_ALIVE}/{status['zid']}"]
    assert tag.tag_id == 7
    assert record["selected"]["tag_id"] == 7
