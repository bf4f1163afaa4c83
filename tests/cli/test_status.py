"""``status``: every answering service's status as JSON on stdout; exit 1 when none answers."""

from __future__ import annotations

import io
import json

import pytest
import zenoh

from tests.helpers import json_objects, loopback_config, open_session
from zenoh_perception.cli import status
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings


def test_the_status_of_a_running_service_is_printed_as_json(endpoint: str) -> None:
    settings = Settings.from_flat(stats_interval_s=0.0, policy="center")
    with open_session(listen=[endpoint]) as session, PerceptionService(session, settings):
        out = io.StringIO()
        code = status.main(loopback_config(connect=[endpoint]), timeout=2.0, out=out)
        zid = str(session.zid())
    assert code == 0
    (reply,) = json.loads(out.getvalue())  # one document: an array of services
    assert (reply["service"], reply["zid"]) == ("zenoh-perception", zid)
    assert reply["settings"] == json.loads(json.dumps(settings.as_dict()))
    assert reply["frames"] == {"received": 0, "processed": 0, "dropped": 0, "rejected": 0}


def test_another_status_key(endpoint: str) -> None:
    settings = Settings.from_flat(stats_interval_s=0.0, status_key="rover/perception/status")
    with open_session(listen=[endpoint]) as session, PerceptionService(session, settings):
        out = io.StringIO()
        conf = loopback_config(connect=[endpoint])
        assert status.main(conf, key="rover/perception/status", timeout=2.0, out=out) == 0
    (reply,) = json_objects(out.getvalue())
    assert reply["settings"] == json.loads(json.dumps(settings.as_dict()))
    assert settings.outputs.status_key == "rover/perception/status"


def test_lines_prints_one_compact_object_per_line(endpoint: str) -> None:
    settings = Settings.from_flat(stats_interval_s=0.0)
    with open_session(listen=[endpoint]) as session, PerceptionService(session, settings):
        out = io.StringIO()
        code = status.main(loopback_config(connect=[endpoint]), timeout=2.0, lines=True, out=out)
        zid = str(session.zid())
    assert code == 0
    (line,) = out.getvalue().splitlines()
    assert json.loads(line)["zid"] == zid


def test_exit_1_naming_the_key_when_no_service_answers(
    endpoint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = io.StringIO()
    code = status.main(loopback_config(listen=[endpoint]), key="a/b", timeout=0.3, out=out)
    assert code == 1
    assert out.getvalue() == ""
    assert "'a/b'" in capsys.readouterr().err


def test_a_reply_that_is_not_json_is_no_service(
    peers: tuple[zenoh.Session, zenoh.Session], endpoint: str
) -> None:
    answering, _ = peers
    queryable = answering.declare_queryable(
        "perception/status", lambda query: query.reply("perception/status", b"<html>")
    )
    try:
        out = io.StringIO()
        assert status.main(loopback_config(connect=[endpoint]), timeout=0.5, out=out) == 1
    finally:
        queryable.undeclare()
