"""A new user's set-up through the real CLI: a mistake is one line that says what to do (exit
code 2, at once), and a service with nothing to do says what it waits for."""

from __future__ import annotations

import os
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
import zenoh

from tests.helpers import (
    REPO,
    OutputLines,
    cli_command,
    open_session,
    parse_pairs,
    run_cli,
    running_cli,
    wait_for_subscriber,
)
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception_bench.scene import render_markers

#: Every subcommand that opens a Zenoh session, with the arguments it needs besides the flags.
SESSION_COMMANDS = [
    ["run"],
    ["echo", "--count", "1"],
    ["status", "--timeout", "0.5"],
    ["replay", "--limit", "1", "tests"],
    ["demo", "--limit", "1"],
]


def _error_line(result: subprocess.CompletedProcess[str]) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("zenoh-perception: error: ")
    return lines[0]


@pytest.mark.parametrize("command", SESSION_COMMANDS, ids=lambda c: c[0])
def test_a_zenoh_config_that_is_dev_zero_is_refused_in_every_command(command: list[str]) -> None:
    line = _error_line(run_cli(*command, "-c", "/dev/zero", timeout=60))
    assert "Zenoh configuration file (-c) /dev/zero is not a regular file" in line


def test_a_zenoh_config_that_is_a_fifo_does_not_hang_status(tmp_path: Path) -> None:
    fifo = tmp_path / "zenoh.json5"
    os.mkfifo(fifo)
    line = _error_line(run_cli("status", "-c", str(fifo), timeout=60))
    assert "is not a regular file" in line


@pytest.mark.parametrize("command", SESSION_COMMANDS, ids=lambda c: c[0])
def test_an_endpoint_without_its_protocol_is_one_line_with_the_right_form(
    command: list[str],
) -> None:
    line = _error_line(run_cli(*command, "-e", "127.0.0.1:7447", timeout=60))
    assert "-e/--connect '127.0.0.1:7447'" in line
    assert "e.g. tcp/127.0.0.1:7447" in line
    assert "Json5Err" not in line


def test_client_mode_with_nowhere_to_connect_exits_2() -> None:
    line = _error_line(run_cli("run", "-m", "client", "--no-multicast-scouting", timeout=60))
    assert "nowhere to connect" in line
    assert "-e tcp/127.0.0.1:7447" in line


def test_zenoh_log_lines_carry_no_colour_codes_away_from_a_terminal() -> None:
    env = {k: v for k, v in os.environ.items() if k != "NO_COLOR"}
    env["RUST_LOG"] = "info"
    result = subprocess.run(
        cli_command("status", "--timeout", "0.2", "--no-multicast-scouting"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env=env,
    )
    # Zenoh's own log (Rust's tracing) writes to stdout
    assert "zenoh::" in result.stdout
    assert "\x1b[" not in result.stdout + result.stderr


def test_run_says_what_it_waits_for_until_the_first_frame(endpoint: str) -> None:
    with (
        open_session(listen=[endpoint]) as camera,
        running_cli(
            "run", "-e", endpoint, "--no-multicast-scouting", "--stats-interval-s", "0.2"
        ) as proc,
    ):
        lines = OutputLines(proc)
        waiting = parse_pairs(lines.wait_for("event=waiting_for_frames"))
        assert waiting["key"] == "zed/left/image"
        publisher = camera.declare_publisher(
            "zed/left/image", congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_for_subscriber(publisher)
        image = render_markers(640, 480, [])
        publisher.put(image.tobytes(), attachment=RawFrameMeta(640, 480).to_msgpack())
        # once a frame came, the periodic line is the counters again
        stats = parse_pairs(lines.wait_for("event=stats"))
        assert int(stats["received"]) >= 1
        publisher.undeclare()


def test_run_hints_once_at_the_dictionary_when_no_frame_has_a_tag(endpoint: str) -> None:
    with (
        open_session(listen=[endpoint]) as camera,
        running_cli(
            "run",
            "-e",
            endpoint,
            "--no-multicast-scouting",
            "--no-tag-hint-s",
            "1",
            "--dictionary",
            "DICT_APRILTAG_16h5",
        ) as proc,
    ):
        lines = OutputLines(proc)
        lines.wait_for("event=started")
        publisher = camera.declare_publisher(
            "zed/left/image", congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_for_subscriber(publisher)
        # a 4X4 tag in view, which a 16h5 service cannot read
        image = render_markers(
            640, 480, [(3, np.array([[100, 100], [300, 100], [300, 300], [100, 300]]))]
        )
        meta = RawFrameMeta(640, 480).to_msgpack()
        stop = threading.Event()

        def camera_loop() -> None:
            while not stop.wait(0.05):
                publisher.put(image.tobytes(), attachment=meta)

        thread = threading.Thread(target=camera_loop, daemon=True)
        thread.start()
        try:
            hint = parse_pairs(lines.wait_for("event=no_tag_hint"))
        finally:
            stop.set()
            thread.join(timeout=5)
            publisher.undeclare()
    assert hint["dictionary"] == "DICT_APRILTAG_16h5"
    assert "zenoh-perception probe" in hint["detail"]
