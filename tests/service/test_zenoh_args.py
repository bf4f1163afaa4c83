"""Zenoh session flags: the config they build, and malformed ones refused as settings errors."""

from __future__ import annotations

import argparse
import json
import os
import socket
from collections.abc import Callable
from pathlib import Path

import pytest

from zenoh_perception.errors import SessionError, SettingsError
from zenoh_perception.service.zenoh_args import (
    RMW_ZENOH_SESSION_DEFAULTS,
    add_zenoh_arguments,
    open_zenoh,
    zenoh_config_from_args,
)
from zenoh_perception.settings import add_settings_arguments


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_settings_arguments(parser)
    add_zenoh_arguments(parser)
    return parser.parse_args(list(argv))


def test_zenoh_flags_build_the_config(tmp_path: Path) -> None:
    args = _parse(
        "-m",
        "client",
        "-e",
        "tcp/127.0.0.1:7447",
        "-e",
        "tcp/127.0.0.1:7448",
        "-l",
        "tcp/127.0.0.1:0",
        "--no-multicast-scouting",
        "--cfg",
        "scouting/delay:123",
    )
    conf = zenoh_config_from_args(args)
    assert conf.get_json("mode") == '"client"'
    assert "7448" in conf.get_json("connect/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "false"
    assert conf.get_json("scouting/delay") == "123"


@pytest.mark.parametrize(
    "argv", [["--cfg", "novalue"], ["--cfg", "no/such/key:1"], ["-c", "/no/such/file.json5"]]
)
def test_bad_zenoh_flags_are_settings_errors(argv: list[str]) -> None:
    with pytest.raises(SettingsError):
        zenoh_config_from_args(_parse(*argv))


def test_flags_override_the_config_file(tmp_path: Path) -> None:
    path = tmp_path / "zenoh.json5"
    path.write_text(
        '{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:7000"] }, // a comment\n'
        "  scouting: { delay: 250 } }\n"
    )
    from_file = zenoh_config_from_args(_parse("-c", str(path)))
    assert json.loads(from_file.get_json("mode")) == "client"
    assert json.loads(from_file.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7000"]
    overridden = zenoh_config_from_args(
        _parse("-c", str(path), "-m", "peer", "-e", "tcp/127.0.0.1:7001", "-e", "tcp/[::1]:7002")
    )
    assert json.loads(overridden.get_json("mode")) == "peer"
    assert json.loads(overridden.get_json("connect/endpoints")) == [
        "tcp/127.0.0.1:7001",
        "tcp/[::1]:7002",
    ]
    assert json.loads(overridden.get_json("scouting/delay")) == 250  # the rest of the file


def test_listen_endpoints_are_repeatable() -> None:
    conf = zenoh_config_from_args(_parse("-l", "tcp/127.0.0.1:7447", "-l", "udp/127.0.0.1:7447"))
    assert json.loads(conf.get_json("listen/endpoints")) == [
        "tcp/127.0.0.1:7447",
        "udp/127.0.0.1:7447",
    ]


def test_a_cfg_value_that_is_not_json5_names_the_problem() -> None:
    with pytest.raises(
        SettingsError, match=r"--cfg scouting/delay: not valid JSON5 at line 1, column 1: expected"
    ):
        zenoh_config_from_args(_parse("--cfg", "scouting/delay:{not json"))


def test_a_session_that_cannot_open_is_a_session_error_naming_the_endpoint() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        conf = zenoh_config_from_args(_parse("-l", endpoint, "--no-multicast-scouting"))
        with pytest.raises(SessionError, match="cannot open the Zenoh session") as info:
            open_zenoh(conf)
    assert endpoint.removeprefix("tcp/") in str(info.value)
    assert "\n" not in str(info.value)


def test_an_open_session_is_returned(endpoint: str) -> None:
    with open_zenoh(zenoh_config_from_args(_parse("-l", endpoint, "--no-multicast-scouting"))) as s:
        assert str(s.zid())


@pytest.mark.parametrize("endpoint", ["127.0.0.1:7447", "tcp:127.0.0.1:7447", "carrier/x", "tcp/"])
def test_an_endpoint_without_its_protocol_names_the_flag_and_the_right_form(
    endpoint: str,
) -> None:
    for flag in ("-e", "-l"):
        with pytest.raises(SettingsError, match=rf"{flag}/--\w+ .*PROTOCOL/ADDRESS") as info:
            zenoh_config_from_args(_parse(flag, endpoint))
        if endpoint == "127.0.0.1:7447":
            assert "e.g. tcp/127.0.0.1:7447" in str(info.value)


def test_client_mode_with_nowhere_to_connect_is_refused() -> None:
    with pytest.raises(SettingsError, match=r"client mode .* nowhere to connect.* -e tcp/"):
        zenoh_config_from_args(_parse("-m", "client", "--no-multicast-scouting"))
    # an endpoint, or multicast scouting allowed, is somewhere to go
    zenoh_config_from_args(_parse("-m", "client", "--no-multicast-scouting", "-e", "tcp/h:1"))
    zenoh_config_from_args(_parse("-m", "client"))


def test_client_mode_from_the_config_file_is_checked_too(tmp_path: Path) -> None:
    path = tmp_path / "client.json5"
    path.write_text('{ mode: "client", scouting: { multicast: { enabled: false } } }')
    with pytest.raises(SettingsError, match="nowhere to connect"):
        zenoh_config_from_args(_parse("-c", str(path)))


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: Path("/dev/zero"), "is not a regular file"),
        (lambda p: p, "is not a regular file"),  # a directory
        (lambda p: _write(p / "big.json5", b"{}" + b" " * (1 << 20)), "larger than 1048576"),
        (lambda p: _write(p / "latin1.json5", b'{ id: "\xe9" }'), "not UTF-8"),
        (lambda p: _write(p / "deep.json5", b"[" * 100_000), "nested 100000 levels"),
        (lambda p: _write(p / "bad.json5", b"{ mode: "), "is invalid"),
    ],
)
def test_a_config_file_is_checked_before_it_is_read_whole(
    tmp_path: Path, make: Callable[[Path], Path], message: str
) -> None:
    with pytest.raises(SettingsError, match=rf"Zenoh configuration file \(-c\) .*{message}"):
        zenoh_config_from_args(_parse("-c", str(make(tmp_path))))


def test_a_config_file_that_is_a_fifo_does_not_hang(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(SettingsError, match="not a regular file"):
        zenoh_config_from_args(_parse("-c", str(fifo)))


def test_a_deeply_nested_cfg_value_is_refused() -> None:
    with pytest.raises(SettingsError, match=r"--cfg scouting/delay is nested"):
        zenoh_config_from_args(_parse("--cfg", "scouting/delay:" + "[" * 10_000))


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_rmw_zenoh_defaults_stand_in_for_zenohs_and_flags_override_them() -> None:
    conf = zenoh_config_from_args(_parse(), RMW_ZENOH_SESSION_DEFAULTS)
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/localhost:7447"]
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/localhost:0"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is True
    moved = zenoh_config_from_args(
        _parse("-e", "tcp/127.0.0.1:7000", "-m", "client"), RMW_ZENOH_SESSION_DEFAULTS
    )
    assert json.loads(moved.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7000"]
    assert json.loads(moved.get_json("mode")) == "client"
    assert json.loads(moved.get_json("listen/endpoints")) == ["tcp/localhost:0"]


def test_a_config_file_replaces_the_rmw_zenoh_defaults(tmp_path: Path) -> None:
    path = tmp_path / "session.json5"
    path.write_text('{ mode: "client" }\n')
    conf = zenoh_config_from_args(_parse("-c", str(path)), RMW_ZENOH_SESSION_DEFAULTS)
    assert json.loads(conf.get_json("mode")) == "client"
    assert "localhost:7447" not in conf.get_json("connect/endpoints")
