"""End to end: the real ``zenoh-perception`` CLI as subprocesses (run, echo, status, demo), fed
from another peer; refusals at start-up exit 2 with one line naming what is wrong."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from tests.helpers import (
    REPO,
    Collector,
    OutputLines,
    cli_command,
    log_events,
    open_session,
    parse_pairs,
    query_status,
    run_cli,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from zenoh_perception.tags.selection import NO_TAG
from zenoh_perception.wire.frames import RawFrameMeta, encode_image_cdr
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.records import FrameRecord, TagCodec, decode_record
from zenoh_perception_bench._loopback import loopback_endpoint
from zenoh_perception_bench.scene import render_markers

W, H = 1280, 720
# Test cameras block rather than let Zenoh drop a large frame when the machine is busy.
_BLOCK = zenoh.CongestionControl.BLOCK


def square(x0: float, y0: float, side: float) -> np.ndarray:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


FRAMES = [
    (render_markers(W, H, [(1, square(100, 100, 120)), (2, square(700, 300, 260))]), 2),
    (render_markers(W, H, []), -1),
    (render_markers(W, H, [(9, square(900, 80, 90)), (4, square(300, 420, 70))]), 9),
]


def test_run_answers_hd720_raw_and_cdr_frames_and_survives_garbage(endpoint: str) -> None:
    with (
        running_cli(
            "run",
            "--settings",
            "config/perception.toml",
            "-l",
            endpoint,
            "--no-multicast-scouting",
            "--stats-interval-s",
            "0.5",
        ) as proc,
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        tags = Collector(camera, "tag")
        records = Collector(camera, "perception/tags")
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        codec = TagCodec()
        for i in range(12):
            image, expected = FRAMES[i % len(FRAMES)]
            stamp = 1_700_000_000_000_000_000 + i
            if i % 2 == 0:
                meta = RawFrameMeta(W, H, stamp_ns=stamp, seq=i, frame_id="zed_left")
                publisher.put(image.tobytes(), attachment=meta.to_msgpack())
            else:
                publisher.put(bytes(encode_image_cdr(image, "bgra8", stamp_ns=stamp)))
            tag = codec.decode(tags.get(timeout=20).payload)
            record = decode_record(records.get(timeout=20).payload)
            assert tag.tag_id == expected
            assert record["selected"]["tag_id"] == tag.tag_id
            assert record["selected"]["closeness_metric"] == tag.closeness_metric
            assert record["stamp_ns"] == stamp
            if i % 3 == 1:  # garbage between good frames never kills the service
                publisher.put(b"\xde\xad\xbe\xef" * 10)
                publisher.put(b"1234", attachment=b"\x92\x01")
        assert proc.poll() is None

        def frames() -> dict[str, int]:
            status = query_status(camera)
            return {} if status is None else dict(status["frames"])

        # 12 frames and 8 garbage payloads: each garbage payload is rejected, or dropped when
        # the next frame replaces it in the mailbox; a frame is counted once it is answered
        wait_until(
            lambda: frames().get("processed") == 12 and frames().get("received") == 20,
            what="12 frames answered and counted",
        )
        counted = frames()
        assert counted["dropped"] + counted["rejected"] == 8
    assert proc.returncode == 0


def test_echo_prints_tags_and_status_reports(endpoint: str) -> None:
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting"),
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        echo = subprocess.Popen(
            cli_command(
                "echo",
                "-e",
                endpoint,
                "--no-multicast-scouting",
                "--json",
                "--count",
                "2",
                "--timeout",
                "60",
            ),
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            publisher = camera.declare_publisher("zed/left/image")
            # Keep feeding until echo has what it needs (it subscribes at its own pace).
            deadline = time.monotonic() + 60
            image = FRAMES[0][0]
            meta = RawFrameMeta(W, H).to_msgpack()
            while echo.poll() is None and time.monotonic() < deadline:
                publisher.put(image.tobytes(), attachment=meta)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    echo.wait(timeout=0.5)
            out, err = echo.communicate(timeout=10)
        finally:
            if echo.poll() is None:
                echo.kill()
                echo.communicate()
        assert echo.returncode == 0, err
        lines = [json.loads(line) for line in out.splitlines()]
        assert len(lines) == 2
        tag_lines = [line for line in lines if line["key"] == "tag"]
        record_lines = [line for line in lines if line["key"] == "perception/tags"]
        assert all(line["tag_id"] == 2 for line in tag_lines)
        assert all(line["selected"]["tag_id"] == 2 for line in record_lines)

        status = run_cli(
            "status", "-e", endpoint, "--no-multicast-scouting", "--timeout", "5", timeout=60
        )
        assert status.returncode == 0, status.stderr
        (reply,) = json.loads(status.stdout)  # one JSON document: an array of services
        assert reply["service"] == "zenoh-perception"


def test_status_exits_1_when_no_service_answers(endpoint: str) -> None:
    result = run_cli(
        "status", "-l", endpoint, "--no-multicast-scouting", "--timeout", "0.5", timeout=60
    )
    assert result.returncode == 1
    assert "no perception service answered" in result.stderr


def test_sigterm_exits_0_within_2_seconds(endpoint: str) -> None:
    with running_cli("run", "-l", endpoint, "--no-multicast-scouting") as proc:
        with open_session(connect=[endpoint]) as probe:
            wait_for_status(probe)
        started = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
        elapsed = time.monotonic() - started
        output = proc.stdout.read() if proc.stdout else ""
    assert proc.returncode == 0, output
    assert elapsed < 2.0, f"took {elapsed:.2f} s"
    assert [e["signal"] for e in log_events(output, "signal")] == ["SIGTERM"]
    (stopped,) = log_events(output, "stopped")
    assert stopped["received"] == "0"


def test_invalid_settings_exit_2_with_a_message() -> None:
    result = run_cli("run", "--policy", "nearest", "--no-multicast-scouting", timeout=60)
    assert result.returncode == 2
    assert "policy must be one of" in result.stderr


def test_demo_runs_camera_service_and_echo_in_one_command() -> None:
    result = run_cli(
        "demo",
        "--no-multicast-scouting",
        "--limit",
        "12",
        "--fps",
        "30",
        "--stats-interval-s",
        "0",
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    answers = [parse_pairs(line) for line in lines if line.startswith("[perception/tags] ")]
    # how many of the 12 frames are answered depends on the machine's load (latest-frame-wins
    # skips frames): tests/camera/test_demo.py waits for answers in process
    assert answers
    assert {int(a["seq"]) for a in answers} <= set(range(12))
    truth = [line for line in lines if line.startswith("  truth:")]
    assert len(truth) == len(answers)  # every answer compared with the frame's truth
    assert all(" tags in view; read " in line and "; not read " in line for line in truth)
    summary, opencv = lines[-2:]
    assert summary.startswith(f"demo: {len(answers)} of 12 frames answered"), summary
    # the tag a rover steers by is never a look-alike; OpenCV's default on the same frames
    # stands beside it
    assert summary.endswith("0 selected (the tag a rover steers by) where no such tag is")
    assert opencv.startswith(f"demo: OpenCV's default detector on the same {len(answers)} frames")


def test_demo_camera_only_feeds_a_separate_service(endpoint: str) -> None:
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting"),
        open_session(connect=[endpoint]) as probe,
    ):
        wait_for_status(probe)
        records = Collector(probe, "perception/tags")
        camera = run_cli(
            "demo",
            "--camera-only",
            "--format",
            "cdr",
            "-e",
            endpoint,
            "--no-multicast-scouting",
            "--limit",
            "20",
            "--fps",
            "20",
        )
        assert camera.returncode == 0, camera.stderr
        record = decode_record(records.get(timeout=20).payload)
        assert record["source"] == "cdr" and record["frame_id"] == "demo"


#: A service that wrongly starts is stopped by this timeout (the test then fails).
_START_TIMEOUT_S = 30.0


def _refused(*args: str) -> str:
    """Run ``run ARGS``; assert it stops at once with exit 2 and a one-line error; return it."""
    result = run_cli("run", "--no-multicast-scouting", *args, timeout=_START_TIMEOUT_S)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("zenoh-perception: error: ")
    return lines[0]


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (("--tag-key", "perception/*"), "tag_key"),
        (("--record-key", "zed/left/image"), "record_key"),
        (("--input-key", "**"), "tag_key"),
        (("--status-key", "a//b"), "status_key"),
        (("--ros-package", "Not-A-Package"), "ros_package"),
        (("--opencv-threads", str(4 * (os.cpu_count() or 1) + 1)), "opencv_threads"),
        (("--stats-interval-s", "0.01"), "stats_interval_s"),
        (("--camera-fx", "1e9", "--camera-fy", "1e9"), "camera_fx"),
    ],
)
def test_run_refuses_invalid_settings_naming_the_setting(
    flags: tuple[str, ...], named: str
) -> None:
    assert named in _refused(*flags)


def _fifo(tmp_path: Path) -> Path:
    path = tmp_path / "fifo.toml"
    os.mkfifo(path)
    return path


def _huge(tmp_path: Path) -> Path:
    path = tmp_path / "huge.toml"
    path.write_text(("# " + "x" * 1021 + "\n") * 1025)
    return path


def _latin1(tmp_path: Path) -> Path:
    path = tmp_path / "latin1.toml"
    path.write_bytes('# caf\u00e9\ntag_key = "tag"\n'.encode("latin-1"))
    return path


@pytest.mark.parametrize(
    ("make", "says"),
    [(_fifo, "not a regular file"), (_huge, "larger than 1048576"), (_latin1, "not UTF-8")],
)
def test_run_refuses_settings_files_that_are_not_small_regular_utf8_files(
    tmp_path: Path, make: Callable[[Path], Path], says: str
) -> None:
    path = make(tmp_path)
    line = _refused("--settings", str(path))
    assert str(path) in line and says in line


def test_run_with_its_listen_port_in_use_prints_one_line_and_exits_2() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        line = _refused("-l", f"tcp/127.0.0.1:{port}")
        status = run_cli("status", "--no-multicast-scouting", "-l", f"tcp/127.0.0.1:{port}")
    assert "cannot open the Zenoh session" in line
    assert f"127.0.0.1:{port}" in line and "Address already in use" in line
    # The other commands open their sessions the same way.
    assert status.returncode == 2, status.stderr
    assert status.stderr.strip().splitlines() == [line]


def test_run_refuses_a_frame_limit_that_zenoh_would_drop() -> None:
    line = _refused(
        "--max-frame-bytes", "2000000", "--cfg", "transport/link/rx/max_message_size:1000000"
    )
    assert "max_frame_bytes = 2000000" in line
    assert "transport/link/rx/max_message_size = 1000000" in line


def test_demo_refuses_frames_over_max_frame_bytes() -> None:
    result = run_cli(
        "demo",
        "--camera-only",
        "--no-multicast-scouting",
        "--resolution",
        "VGA",
        "--limit",
        "1",
        "--max-frame-bytes",
        "100000",
        timeout=60,
    )
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert "is 1228800 bytes, over max_frame_bytes = 100000" in result.stderr
    assert "transport/link/rx/max_message_size" in result.stderr


def _record(seq: int) -> bytes:
    return FrameRecord(
        stamp_ns=seq,
        frame_id="cam",
        seq=seq,
        width=64,
        height=48,
        selected=NO_TAG,
        tags=(),
        timing_ms={"latency_ms": 1.0},
        source=InputKind.RAW,
    ).to_msgpack()


def test_echo_prints_and_counts_gaps_in_the_record_seq(endpoint: str) -> None:
    with open_session(listen=[endpoint]) as service:
        echo = subprocess.Popen(
            cli_command(
                "echo",
                "-e",
                endpoint,
                "--no-multicast-scouting",
                "--json",
                "--count",
                "5",
                "--timeout",
                "60",
            ),
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            publisher = service.declare_publisher("perception/tags")
            wait_for_subscriber(publisher, timeout=60)
            for seq in (1, 2, 5, 6, 9):
                publisher.put(_record(seq))
            out, err = echo.communicate(timeout=60)
        finally:
            if echo.poll() is None:
                echo.kill()
                echo.communicate()
    assert echo.returncode == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    gaps = [line["gap"] for line in lines if "gap" in line]
    assert gaps == [{"after": 2, "next": 5, "missing": 2}, {"after": 6, "next": 9, "missing": 2}]
    assert [line["seq"] for line in lines if "seq" in line] == [1, 2, 5, 6, 9]
    (summary,) = [line for line in err.splitlines() if line.startswith("echo: records=")]
    assert parse_pairs(summary) == {"records": "5", "gaps": "2", "missing": "4", "restarts": "0"}


def test_a_second_service_on_the_same_keys_is_reported_by_both(endpoint: str) -> None:
    other = loopback_endpoint()
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting") as first,
        running_cli("run", "-l", other, "-e", endpoint, "--no-multicast-scouting") as second,
    ):
        for proc in (first, second):
            fields = parse_pairs(OutputLines(proc).wait_for("event=another_service"))
            assert fields["level"] == "WARNING"
            assert fields["tag"] == "tag"
            assert "--share-group" in fields["detail"]


def test_run_warns_when_its_connect_endpoint_stays_unreachable(endpoint: str) -> None:
    nowhere = loopback_endpoint()  # nothing listens there
    with running_cli("run", "-l", endpoint, "-e", nowhere, "--no-multicast-scouting") as proc:
        fields = parse_pairs(OutputLines(proc).wait_for("event=unreachable"))
    assert fields["level"] == "WARNING"
    assert fields["connect"] == nowhere


def test_run_says_nothing_of_endpoints_it_reached(endpoint: str) -> None:
    with (
        open_session(listen=[endpoint]) as peer,
        running_cli("run", "-e", endpoint, "--no-multicast-scouting") as proc,
    ):
        lines = OutputLines(proc)
        # the warning would come CONNECT_WARNING_S (5 s) after the start, checked every 0.5 s:
        # wait until the service's own clock is well past that, then read its whole output
        wait_until(
            lambda: (query_status(peer) or {"uptime_s": 0.0})["uptime_s"] >= 6.5,
            timeout=30.0,
            what="the service up for 6.5 s",
        )
        proc.send_signal(signal.SIGINT)
        lines.rest()  # up to the end of its output
        assert proc.wait(timeout=10) == 0
    output = "".join(lines.seen)
    assert log_events(output, "started") and log_events(output, "stopped")
    assert log_events(output, "unreachable") == []


def test_status_gathers_every_service_for_its_whole_timeout(endpoint: str) -> None:
    other = loopback_endpoint()
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting") as first,
        running_cli("run", "-l", other, "-e", endpoint, "--no-multicast-scouting") as second,
    ):
        for proc in (first, second):
            OutputLines(proc).wait_for("event=another_service")  # both up and linked
        started = time.monotonic()
        result = run_cli("status", "-e", endpoint, "--no-multicast-scouting", "--timeout", "3")
        took = time.monotonic() - started
    assert result.returncode == 0, result.stderr
    replies = json.loads(result.stdout)  # one document, however many services answer
    assert len({reply["zid"] for reply in replies}) == 2
    assert took >= 3.0  # it listened for the whole timeout


def _record_with_seq(records: Collector, seq: int) -> dict[str, Any]:
    while True:
        record = decode_record(records.get(timeout=30).payload)
        if record["seq"] == seq:
            return record


def _frame_ms(timing: dict[str, float]) -> float:
    return timing["decode_ms"] + timing["convert_ms"] + timing["detect_ms"]


def test_run_refuses_oversized_frames_and_reports_the_per_frame_budget(endpoint: str) -> None:
    """A 4-megapixel frame is refused by size (BGRA, 16 MB) or by pixels (mono8, 4 MB); 2 MP
    frames within both limits are answered, and status reports their worst times, the frames
    over a 1 ms budget and the frame rate as frames over wall time."""
    flags = (
        "--max-frame-bytes", "9000000",
        "--max-frame-pixels", "3000000",
        "--frame-budget-ms", "1",
        "--stats-interval-s", "0",
        "--log-interval-s", "60",
    )  # fmt: skip
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting", *flags) as proc,
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        records = Collector(camera, "perception/tags")
        publisher = camera.declare_publisher("zed/left/image", congestion_control=_BLOCK)
        wait_for_subscriber(publisher)

        def rejected() -> dict[str, int]:
            status = query_status(camera)
            return {} if status is None else dict(status["rejected_by_reason"])

        big = np.zeros((1600, 2560, 4), dtype=np.uint8)
        publisher.put(big.tobytes(), attachment=RawFrameMeta(2560, 1600).to_msgpack())
        wait_until(lambda: rejected() == {"payload_too_large": 1}, what="size rejection")
        grey = np.ascontiguousarray(big[:, :, 0])
        publisher.put(grey.tobytes(), attachment=RawFrameMeta(2560, 1600, "mono8").to_msgpack())
        wait_until(
            lambda: rejected() == {"payload_too_large": 1, "too_many_pixels": 1},
            what="pixel rejection",
        )
        frame = render_markers(1920, 1080, [(7, square(800, 400, 300))])
        timings: list[dict[str, float]] = []
        for seq in range(3):
            meta = RawFrameMeta(1920, 1080, seq=seq).to_msgpack()
            publisher.put(frame.tobytes(), attachment=meta)
            record = _record_with_seq(records, seq)
            assert record["selected"]["tag_id"] == 7
            timings.append(record["timing"])
        # a frame is counted once its record is out: wait for the count, do not race it
        wait_until(
            lambda: (query_status(camera) or {"frames": {}})["frames"].get("processed") == 3,
            what="three frames counted",
        )
        answered = query_status(camera)
        assert answered is not None
        # A quiet second of the service's own clock after the last answer.
        wait_until(
            lambda: (query_status(camera) or answered)["uptime_s"] >= answered["uptime_s"] + 1.0,
            what="a quiet second",
        )
        status = query_status(camera)
        assert status is not None
        assert proc.poll() is None
    assert status["frames"]["processed"] == 3
    assert status["rejected_by_reason"] == {"payload_too_large": 1, "too_many_pixels": 1}
    budget = status["budget"]
    assert budget["frame_budget_ms"] == 1.0
    assert budget["detect_ms_max"] == pytest.approx(max(t["detect_ms"] for t in timings), abs=2e-3)
    assert budget["frame_ms_max"] == pytest.approx(max(_frame_ms(t) for t in timings), abs=2e-3)
    assert budget["over_budget"] == sum(_frame_ms(t) > 1.0 for t in timings)
    # Frames over wall time: the three frames over the window (5 s, or the uptime if shorter).
    assert status["fps"] == pytest.approx(3 / min(5.0, status["uptime_s"]), rel=0.01)
