"""Asking running services for their status: one reply per service, gathered over the whole
timeout, replies that are not a JSON object left out."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import pytest
import zenoh

from tests.helpers import loopback_endpoint, open_session, wait_until
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.service.status import query_status
from zenoh_perception.settings import Settings

SETTINGS = Settings.from_flat(stats_interval_s=0.0)


def _alive(session: zenoh.Session) -> list[str]:
    """The liveliness tokens of the services ``session`` reaches."""
    replies = session.liveliness().get("perception/alive/*", timeout=1.0)
    return [str(reply.ok.key_expr) for reply in replies if reply.ok is not None]


@pytest.fixture
def two_services(endpoint: str) -> Iterator[tuple[zenoh.Session, list[str]]]:
    """A client session that reaches two running services; their zids."""
    other = loopback_endpoint()
    with (
        open_session(listen=[endpoint]) as first,
        open_session(listen=[other]) as second,
        open_session(connect=[endpoint, other]) as client,
        PerceptionService(first, SETTINGS),
        PerceptionService(second, SETTINGS),
    ):
        wait_until(lambda: len(_alive(client)) == 2, what="both services reachable")
        yield client, sorted([str(first.zid()), str(second.zid())])


def test_gathering_lasts_the_whole_timeout(peers: tuple[zenoh.Session, zenoh.Session]) -> None:
    service_side, client = peers
    with PerceptionService(service_side, SETTINGS):
        started = time.monotonic()
        replies = query_status(client, timeout=1.0)
        took = time.monotonic() - started
    assert [reply["zid"] for reply in replies] == [str(service_side.zid())]  # one per service
    assert replies[0]["service"] == "zenoh-perception"
    assert took >= 1.0  # asked again until the timeout, for services found late


def test_one_query_hears_every_service(two_services: tuple[zenoh.Session, list[str]]) -> None:
    client, zids = two_services
    replies = query_status(client, timeout=1.0, gather=False)
    assert sorted(reply["zid"] for reply in replies) == zids


def test_without_gathering_one_query_is_asked(peers: tuple[zenoh.Session, zenoh.Session]) -> None:
    service_side, client = peers
    with PerceptionService(service_side, SETTINGS):
        replies: list[dict[str, object]] = []

        def answered() -> bool:  # the queryable may not be known to the client yet: poll
            replies[:] = query_status(client, timeout=1.0, gather=False)
            return bool(replies)

        wait_until(answered, what="one reply")
    assert [reply["zid"] for reply in replies] == [str(service_side.zid())]


def test_nobody_answering_is_an_empty_list(peers: tuple[zenoh.Session, zenoh.Session]) -> None:
    _nobody, client = peers
    started = time.monotonic()
    assert query_status(client, timeout=0.5) == []
    assert time.monotonic() - started >= 0.5


def test_replies_that_are_not_a_json_object_are_left_out(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> None:
    answering, client = peers
    payloads = [b"not json", b"[1, 2]", json.dumps({"zid": "z1", "service": "x"}).encode()]

    def reply(query: zenoh.Query) -> None:
        for payload in payloads:
            query.reply("perception/status", payload)

    queryable = answering.declare_queryable("perception/status", reply)
    try:
        assert query_status(client, timeout=1.0) == [{"zid": "z1", "service": "x"}]
    finally:
        queryable.undeclare()


def test_the_status_key_can_be_another(peers: tuple[zenoh.Session, zenoh.Session]) -> None:
    service_side, client = peers
    with PerceptionService(
        service_side, Settings.from_flat(stats_interval_s=0.0, status_key="rover/s")
    ):
        assert query_status(client, timeout=0.5) == []
        (reply,) = query_status(client, key="rover/s", timeout=1.0)
    assert reply["settings"]["status_key"] == "rover/s"
