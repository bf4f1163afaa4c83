"""The command line's parser: subcommands, mistyped flags, errors as exit codes."""

from __future__ import annotations

import argparse
import json
import socket
from pathlib import Path

import pytest

from zenoh_perception import __version__
from zenoh_perception.camera import replay
from zenoh_perception.camera.defaults import DEFAULT_COMPRESSED_KEY, DEFAULT_FRAME_ID, DEFAULT_KEY
from zenoh_perception.cli import commands
from zenoh_perception.cli import main as cli
from zenoh_perception.settings import Settings, settings_from_args


@pytest.mark.parametrize(
    ("argv", "hint"),
    [
        (["run", "--tag-kye", "x"], "--tag-kye: did you mean --tag-key?"),
        (["bench", "--datset", "m.json"], "--datset: did you mean --dataset?"),
        (["echo", "--jsn"], "--jsn: did you mean --json?"),
    ],
)
def test_a_mistyped_flag_names_the_closest_one(
    argv: list[str], hint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()  # the suggestion first, no usage dump
    assert line.startswith(f"zenoh-perception {argv[0]}: error: {hint} (unrecognized arguments")


def test_an_unknown_flag_without_a_close_one_shows_the_subcommands_usage(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["run", "--zzzzzzzz"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: zenoh-perception run ")
    assert "zenoh-perception run: error: unrecognized arguments: --zzzzzzzz" in err


@pytest.fixture(autouse=True)
def _keep_logging(monkeypatch: pytest.MonkeyPatch) -> None:
    """``main`` configures the process's logging: not pytest's, here."""
    monkeypatch.setattr(cli, "configure_logging", lambda level: None)


def _subcommands() -> set[str]:
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return set(sub.choices)


def test_the_subcommands() -> None:
    assert _subcommands() == {
        *("run", "demo", "echo", "status", "replay", "probe", "bench", "view"),
        "bridge-config",
        "router",
    }


@pytest.mark.parametrize("command", sorted(_subcommands()))
def test_each_subcommand_has_a_handler(command: str) -> None:
    argv = [command, "recording.mcap"] if command in {"replay", "probe"} else [command]
    args = cli.build_parser().parse_args(argv)
    assert callable(args.handler)
    assert args.command == command


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.split() == ["zenoh-perception", __version__]


def test_an_invalid_setting_exits_2_naming_it(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "--policy", "nearest", "--no-multicast-scouting"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("zenoh-perception: error: ") and "policy" in line


def test_a_session_that_cannot_open_exits_2_naming_the_endpoint(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        code = cli.main(["status", "-l", endpoint, "--no-multicast-scouting", "--timeout", "0.1"])
    assert code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "cannot open the Zenoh session" in line and endpoint.removeprefix("tcp/") in line


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["replay", "x", "--rate", "0"], "--rate"),
        (["replay", "x", "--rate", "nan"], "--rate"),
        (["replay", "x", "--limit", "-1"], "--limit"),
        (["replay", "x", "--max-frame-bytes", "10"], "max_frame_bytes"),
        (["replay", "x", "--subscriber-timeout", "-5"], "--subscriber-timeout"),
        (["replay", "x", "--rate", "5", "--as-fast-as-possible"], "--as-fast-as-possible"),
        (["demo", "--resolution", "8K"], "--resolution"),
    ],
)
def test_bad_flag_values_exit_2_naming_the_flag(
    argv: list[str], named: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2
    assert named in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flags", "key"),
    [
        (["--compressed", "jpeg"], DEFAULT_COMPRESSED_KEY),
        (["--compressed", "png", "--key", "cam/c"], "cam/c"),
    ],
)
def test_replay_compressed_goes_to_the_compressed_key_unless_told(
    flags: list[str], key: str
) -> None:
    args = cli.build_parser().parse_args(["replay", "bag", *flags])
    options = replay.options_from_args(args, stderr_is_tty=False)
    assert (options.key, options.compressed) == (key, flags[1])


def test_replay_flags_have_the_camera_defaults() -> None:
    args = cli.build_parser().parse_args(["replay", "bag"])
    assert (args.frame_id, args.rate, args.limit, args.compressed) == (
        DEFAULT_FRAME_ID,
        None,
        0,
        None,
    )
    options = replay.options_from_args(args, stderr_is_tty=False)
    assert (options.key, options.compressed) == (DEFAULT_KEY, None)
    assert args.max_frame_bytes == Settings().limits.max_frame_bytes
    assert args.wait_for_subscriber is True and args.subscriber_timeout is None


def _queue_size(*argv: str) -> int:
    args = cli.build_parser().parse_args(["run", *argv])
    conf = commands.run_config(args, settings_from_args(args))
    size: int = json.loads(conf.get_json("transport/link/tx/queue/size/data"))
    return size


def test_run_gives_each_link_room_for_a_frames_outputs(tmp_path: Path) -> None:
    # Zenoh's default (2) dropped a frame's third output when its transmit task was late.
    assert _queue_size() == _queue_size("--ros-transport", "rmw_zenoh") == 16
    assert _queue_size("--cfg", "transport/link/tx/queue/size/data:4") == 4
    session = tmp_path / "session.json5"
    session.write_text('{ mode: "peer" }\n', encoding="utf-8")
    assert _queue_size("-c", str(session)) == 2  # a config file is the user's whole say
