"""The first hour with several cameras: the README's "Several cameras" and "Several machines"
commands, read from the README itself and run as written with the real CLI (router included).

Only what keeps the tests apart from each other is added: ``--no-multicast-scouting`` on every
command, the service's ``-l``/the others' ``-e`` on one loopback endpoint, and the README's
hosts (``tcp/0.0.0.0:7447``, ``tcp/rover:7447``, ``tcp/base:7447``) as loopback endpoints.
Two videos of markers, ``front.mp4`` and ``rear.mp4``, are the rover's cameras; a second camera
is the README's camera line with ``front`` replaced by ``rear``.
"""

from __future__ import annotations

import json
import re
import shlex
import signal
import subprocess
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tests.helpers import (
    REPO,
    OutputLines,
    cli_command,
    loopback_endpoint,
    parse_pairs,
    running_cli,
    wait_until,
)

README = REPO / "README.md"
W, H = 320, 240
#: The marker each camera shows.
MARKERS = {"front": 1, "rear": 2}


def section(title: str) -> str:
    """The README's section ``## title``, up to the next ``## ``."""
    text = README.read_text(encoding="utf-8")
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end != -1 else len(text)]


def commands(text: str) -> list[list[str]]:
    """Each ``zenoh-perception`` command of the first ``sh`` block of ``text``, split as a
    shell would (continuation lines joined, comments dropped), without the program name."""
    block = re.search(r"```sh\n(.*?)```", text, re.DOTALL)
    assert block is not None, "no sh block"
    joined = block.group(1).replace("\\\n", " ")
    found = [shlex.split(line, comments=True) for line in joined.splitlines()]
    assert all(argv[0] == "zenoh-perception" for argv in found if argv), found
    return [argv[1:] for argv in found if argv]


def write_video(path: Path, tag_id: int) -> None:
    """A short video of one DICT_4X4_50 marker on white."""
    marker = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), tag_id, 96
    )
    frame = np.full((H, W, 3), 255, np.uint8)
    frame[72:168, 112:208] = marker[:, :, None]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), 10.0, (W, H))
    assert writer.isOpened()
    try:
        for _ in range(10):
            writer.write(frame)
    finally:
        writer.release()


@pytest.fixture
def cameras(tmp_path: Path) -> Path:
    for name, tag_id in MARKERS.items():
        write_video(tmp_path / f"{name}.mp4", tag_id)
    return tmp_path


@contextmanager
def started(argv: Sequence[str], cwd: Path) -> Iterator[tuple[subprocess.Popen[str], OutputLines]]:
    """The real CLI running ``argv`` in ``cwd``, with its output lines to wait on."""
    with running_cli(*argv, cwd=cwd) as proc:
        yield proc, OutputLines(proc)


def run(argv: Sequence[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        cli_command(*argv), cwd=cwd, capture_output=True, text=True, timeout=timeout, check=False
    )


def as_rear(argv: Sequence[str]) -> list[str]:
    return [arg.replace("front", "rear") for arg in argv]


def test_the_readme_names_no_router_it_does_not_ship() -> None:
    for title in ("Several cameras", "Several machines"):
        for argv in commands(section(title)):
            assert argv[0] in {"run", "replay", "echo", "view", "router", "status"}, argv


def test_several_cameras_as_the_readme_says(cameras: Path) -> None:
    run_cmd, camera, echo, view = commands(section("Several cameras"))
    endpoint = loopback_endpoint()
    apart = ["--no-multicast-scouting"]
    joined = [*apart, "-e", endpoint]
    with ExitStack() as stack:
        _, service = stack.enter_context(started([*run_cmd, *apart, "-l", endpoint], cameras))
        begun = parse_pairs(service.wait_for("event=started", timeout=60))
        assert begun["listen"] == endpoint and len(begun["zid"]) >= 16
        _, printed = stack.enter_context(started([*echo, *joined, "--json"], cameras))
        for argv in (camera, as_rear(camera)):
            stack.enter_context(started([*argv, *joined], cameras))
        seen: dict[str, int] = {}
        while len(seen) < len(MARKERS):
            line = json.loads(printed.wait_for('"tag_id"', timeout=60))
            if line["key"].endswith("/tag") and line["tag_id"] >= 0:
                seen[line["key"]] = line["tag_id"]
        assert seen == {"rover/front/tag": 1, "rover/rear/tag": 2}
        shown = run([*view, *joined], cameras)
        assert shown.returncode == 0, shown.stdout + shown.stderr
        assert "saved front.jpg" in shown.stdout
        assert cv2.imread(str(cameras / "front.jpg")) is not None


def _statuses(argv: Sequence[str], cwd: Path) -> list[dict[str, Any]]:
    result = run(argv, cwd)
    if result.returncode != 0:
        return []
    replies = json.loads(result.stdout)  # one JSON document: an array of services
    assert isinstance(replies, list)
    return replies


def _held(replies: list[dict[str, Any]]) -> list[list[str]]:
    return sorted(sorted(reply["group"]["held"]) for reply in replies if reply.get("group"))


def test_several_machines_as_the_readme_says(cameras: Path) -> None:
    rover_router, base_router, camera, instance, status = commands(section("Several machines"))
    rover, base = loopback_endpoint(), loopback_endpoint()

    def placed(argv: Sequence[str], listen: str | None = None) -> list[str]:
        hosts = {"tcp/rover:7447": rover, "tcp/base:7447": base}
        if listen is not None:
            hosts["tcp/0.0.0.0:7447"] = listen
        return [*(hosts.get(arg, arg) for arg in argv), "--no-multicast-scouting"]

    with ExitStack() as stack:
        for argv, listen in ((rover_router, rover), (base_router, base)):
            _, lines = stack.enter_context(started(placed(argv, listen), cameras))
            assert listen in lines.wait_for("listening on", timeout=60)
        for argv in (camera, as_rear(camera)):
            stack.enter_context(started(placed(argv), cameras))
        instances = [stack.enter_context(started(placed(instance), cameras)) for _ in range(2)]
        for _, lines in instances:
            begun = parse_pairs(lines.wait_for("event=started", timeout=60))
            assert (begun["mode"], begun["connect"]) == ("client", base)
        wanted = [["rover/front/image"], ["rover/rear/image"]]
        wait_until(
            lambda: _held(_statuses(placed(status), cameras)) == wanted,
            timeout=90,
            what="each instance holding one camera",
        )
        # one instance killed: the other takes its camera over
        (killed, _), _ = instances
        killed.send_signal(signal.SIGKILL)
        wait_until(
            lambda: (
                _held(_statuses(placed(status), cameras))
                == [["rover/front/image", "rover/rear/image"]]
            ),
            timeout=90,
            what="the other instance holding both cameras",
        )


def _refusal(*flags: str) -> list[str]:
    result = run(["run", "--no-multicast-scouting", *flags], REPO, timeout=60)
    assert result.returncode == 2, result.stderr
    return result.stderr.strip().splitlines()


def test_a_wildcard_input_is_refused_once_with_every_key_and_a_command_that_starts() -> None:
    lines = _refusal("--input-key", "rover/*/image")
    assert "change 4 key(s)" in lines[0]
    named = [line.split(" = ")[0].strip() for line in lines[1:5]]
    assert named == ["tag_key", "record_key", "debug_image_key", "detections_key"]
    # each key its own example, and the flags line starts the service as printed
    flags = shlex.split(lines[6])
    assert flags[:2] == ["--tag-key", "rover/{stream}/tag"]
    assert "rover/{stream}/perception/tags" in flags
    endpoint = loopback_endpoint()
    argv = ["run", "--input-key", "rover/*/image", *flags, "--no-multicast-scouting"]
    with started([*argv, "-l", endpoint], REPO) as (_, output):
        begun = parse_pairs(output.wait_for("event=started", timeout=60))
    # the compressed input followed the camera key, as image_transport names it
    assert begun["compressed_input"] == "rover/*/image/compressed"


def test_a_mistyped_placeholder_is_named_as_unknown() -> None:
    (line,) = _refusal("--input-key", "rover/*/image", "--tag-key", "rover/{camera}/tag")
    assert "unknown placeholder" in line and "'{camera}'" in line


def test_a_concrete_compressed_key_beside_a_pattern_is_still_refused() -> None:
    flags = ["--input-key", "rover/*/image", "--compressed-input-key", "zed/left/image/compressed"]
    lines = _refusal(*flags)
    assert any(
        line.startswith("  compressed_input_key = 'zed/left/image/compressed'") for line in lines
    )
    assert "--compressed-input-key 'rover/*/image/compressed'" in lines[-6]
