"""End to end: what a hostile peer, file or flag does to the real CLI. Each case is a finding of
an attacker's review on loopback: the process must skip and count what it cannot decode, log
one escaped line per reason, and refuse bad flags and settings with one line and exit 2
(docs/robustness.md lists every case with its limit and counter)."""

from __future__ import annotations

import json
import re
import signal
import struct
import subprocess
import zlib
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import msgpack
import numpy as np
import pytest
import zenoh
from rosbags.rosbag2 import StoragePlugin, Writer

from tests.helpers import (
    Collector,
    OutputLines,
    json_objects,
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
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception.tags.selection import TagMessage, TagObservation
from zenoh_perception.wire.frames import RawFrameMeta, encode_image_cdr
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.messages import CAMERA_INFO_TYPE, IMAGE_TYPE, TYPESTORE, header
from zenoh_perception.wire.records import FrameRecord, TagCodec, decode_record
from zenoh_perception_bench.scene import render_markers

FRAMES = "zed/left/image"
_BLOCK = zenoh.CongestionControl.BLOCK


def _rogue_status(session: zenoh.Session, payload: bytes) -> zenoh.Queryable[None]:
    return session.declare_queryable(
        "perception/status", lambda query: query.reply("perception/status", payload)
    )


def test_status_skips_and_counts_rogue_replies_and_prints_the_real_service(
    endpoint: str,
) -> None:
    with (
        open_session(listen=[endpoint]) as session,
        PerceptionService(session, Settings.from_flat(stats_interval_s=0.0)),
        open_session(connect=[endpoint]) as rogue,
    ):
        nested = _rogue_status(rogue, b"[" * 200_000 + b"]" * 200_000)
        nan = _rogue_status(rogue, b'{"zid": "rogue", "x": NaN}')
        try:
            result = run_cli("status", "-e", endpoint, "--no-multicast-scouting", "--timeout", "2")
        finally:
            nested.undeclare()
            nan.undeclare()
        zid = str(session.zid())
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert "NaN" not in result.stdout
    (reply,) = json_objects(result.stdout)
    assert reply["zid"] == zid
    assert "too_deep" in result.stderr
    assert "non_finite" in result.stderr


def test_liveliness_spam_is_one_rate_limited_line_and_a_clean_shutdown(endpoint: str) -> None:
    spam = 10_000
    with (
        running_cli(
            "run",
            "-l",
            endpoint,
            "--no-multicast-scouting",
            "--stats-interval-s",
            "0",
            "--log-interval-s",
            "3600",
        ) as proc,
        open_session(connect=[endpoint]) as attacker,
    ):
        wait_for_status(attacker)
        tokens = [
            attacker.liveliness().declare_token(f"perception/alive/spam{i}") for i in range(spam)
        ]

        def counted() -> bool:
            status = query_status(attacker)
            return status is not None and status["liveliness"]["other_services"] >= spam

        wait_until(counted, timeout=120, what="every token seen by the service")
        proc.send_signal(signal.SIGINT)
        output = OutputLines(proc).rest(timeout=30)
        for token in tokens:
            token.undeclare()
    assert proc.wait(timeout=10) == 0
    text = "".join(output)
    # one line for the event within the interval, whatever the names
    assert len(log_events(text, "another_service")) == 1
    assert "Traceback" not in text
    assert "borrowed" not in text


_CONTROLS = "\x1b[31m\x07\x7f\x9b"


def test_control_characters_from_the_network_reach_the_log_escaped(endpoint: str) -> None:
    with (
        running_cli(
            "run", "-l", endpoint, "--no-multicast-scouting", "--stats-interval-s", "0"
        ) as proc,
        open_session(connect=[endpoint]) as attacker,
    ):
        lines = OutputLines(proc)
        wait_for_status(attacker)
        token = attacker.liveliness().declare_token(f"perception/alive/evil{_CONTROLS}")
        lines.wait_for("event=another_service")
        attachment = msgpack.packb({"width": 1, "height": 1, "encoding": f"x\x00{_CONTROLS}"})
        publisher = attacker.declare_publisher(FRAMES, congestion_control=_BLOCK)
        wait_for_subscriber(publisher)
        publisher.put(b"\x00" * 4, attachment=attachment)
        lines.wait_for("reason=unsupported_encoding")
        token.undeclare()
    seen = "".join(lines.seen)
    assert not re.search(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]", seen), repr(seen)
    assert "\\u001b" in seen  # the escape is written out, not dropped


def test_a_control_character_in_a_setting_exits_2_naming_it(tmp_path: Path) -> None:
    settings = tmp_path / "perception.toml"
    settings.write_text('tag_key = "tag\\u0000x"\n', encoding="utf-8")
    result = run_cli("run", "--settings", str(settings), "--no-multicast-scouting", timeout=30)
    assert result.returncode == 2
    assert "tag_key" in result.stderr
    assert "Traceback" not in result.stderr


def _record(**changes: object) -> bytes:
    tag = TagObservation(4, 50.0, 60.0, 0.5, ((45, 55), (55, 55), (55, 65), (45, 65)), 100.0)
    good = FrameRecord(
        7, "cam", 7, 64, 48, tag.message(), (tag,), {"latency_ms": 1.0}, InputKind.RAW
    ).to_msgpack()
    record = msgpack.unpackb(good)
    record.update(changes)
    packed: bytes = msgpack.packb(record)
    return packed


def _strict_json(line: str) -> object:
    def refuse(name: str) -> object:
        raise AssertionError(f"{name} printed: {line}")

    return json.loads(line, parse_constant=refuse)


def test_echo_skips_and_counts_malformed_records_and_prints_only_json(endpoint: str) -> None:
    bad_records = [
        _record(tags=5),
        _record(timing=[1]),
        _record(selected={"tag_id": "x"}),
        _record(timing={"latency_ms": float("nan")}),
        _record(stamp_ns=float("inf")),
        b"\xc1",
    ]
    nan_tag = bytes(TagCodec().encode(TagMessage(1, float("nan"), 2.0, float("inf"))))
    with (
        running_cli("echo", "-l", endpoint, "--no-multicast-scouting", "--json") as proc,
        open_session(connect=[endpoint]) as attacker,
    ):
        lines = OutputLines(proc)
        lines.wait_for("listening")
        records = attacker.declare_publisher("perception/tags", congestion_control=_BLOCK)
        tags = attacker.declare_publisher("tag", congestion_control=_BLOCK)
        wait_for_subscriber(records)
        wait_for_subscriber(tags)
        tags.put(nan_tag)
        for payload in bad_records:
            records.put(payload)
        records.put(_record(seq=8))
        lines.wait_for('"seq": 8')
        proc.send_signal(signal.SIGINT)
        lines.rest()
    assert proc.wait(timeout=10) == 0
    text = "".join(lines.seen)
    assert "Traceback" not in text
    printed = [_strict_json(line) for line in lines.seen if line.startswith("{")]
    assert [p["seq"] for p in printed if isinstance(p, dict) and "seq" in p] == [8]
    (summary,) = [line for line in text.splitlines() if line.startswith("echo: skipped=")]
    assert parse_pairs(summary)["skipped"] == str(len(bad_records) + 1)


def test_demo_printer_skips_and_counts_what_is_no_record(endpoint: str) -> None:
    with (
        running_cli(
            "demo",
            "-l",
            endpoint,
            "--no-multicast-scouting",
            "--stats-interval-s",
            "0",
            "--fps",
            "10",
        ) as proc,
        open_session(connect=[endpoint]) as attacker,
    ):
        lines = OutputLines(proc)
        records = attacker.declare_publisher("perception/tags", congestion_control=_BLOCK)
        wait_for_subscriber(records)
        records.put(_record(tags=5))
        records.put(_record(timing={"latency_ms": float("inf")}))
        lines.wait_for("undecodable")
        proc.send_signal(signal.SIGINT)
        lines.rest()
    text = "".join(lines.seen)
    assert "Traceback" not in text
    (summary,) = [line for line in text.splitlines() if line.startswith("demo: skipped=")]
    assert parse_pairs(summary)["skipped"] == "2"


def _camera_info_cdr(fx: float, cx: float, cy: float, width: int, height: int) -> bytes:
    types = TYPESTORE.types
    info = types[CAMERA_INFO_TYPE](
        header=header(0, "zed"),
        height=height,
        width=width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array([fx, 0, cx, 0, fx, cy, 0, 0, 1], dtype=np.float64),
        r=np.eye(3).reshape(-1),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )
    return bytes(TYPESTORE.serialize_cdr(info, CAMERA_INFO_TYPE))


def test_camera_info_is_size_limited_and_applies_only_to_frames_of_its_size(
    endpoint: str,
) -> None:
    width, height = 640, 480
    # a 100 px tag of 0.2 m seen fronto-parallel by fx=500 is 1.0 m away
    image = render_markers(
        width, height, [(5, np.array([[270, 190], [370, 190], [370, 290], [270, 290]]))]
    )
    meta = RawFrameMeta(width, height).to_msgpack()
    with (
        running_cli(
            "run",
            "-l",
            endpoint,
            "--no-multicast-scouting",
            "--stats-interval-s",
            "0",
            "--camera-info-key",
            "zed/left/camera_info",
            "--tag-size-m",
            "0.2",
        ),
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        records = Collector(camera, "perception/tags")
        frames = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
        infos = camera.declare_publisher("zed/left/camera_info", congestion_control=_BLOCK)
        wait_for_subscriber(frames)
        wait_for_subscriber(infos)

        def camera_info() -> dict[str, Any]:
            status = query_status(camera)
            assert status is not None
            info: dict[str, Any] = status["camera_info"]
            return info

        def distance() -> object:
            frames.put(image.tobytes(), attachment=meta)
            (tag,) = decode_record(records.get(timeout=30).payload)["tags"]
            return tag.get("distance_m")

        infos.put(b"\x00" * (1 << 20))
        infos.put(_camera_info_cdr(11000.0, 8191.5, 8191.5, 16384, 16384))
        wait_until(lambda: camera_info()["received"] == 2, what="two CameraInfo samples")
        assert camera_info()["rejected_by_reason"] == {"camera_info_too_large": 1}
        assert distance() is None  # intrinsics for 16384x16384 are not these frames'
        assert camera_info()["size_mismatch_frames"] == 1
        infos.put(_camera_info_cdr(500.0, 319.5, 239.5, width, height))
        wait_until(lambda: camera_info()["received"] == 3, what="the third CameraInfo")
        assert distance() == pytest.approx(1.0, rel=0.05)


def _cdr_frame(*, frame_id: str = "cam", sec: int = 1, nanosec: int = 0) -> bytes:
    pixels = np.zeros((4, 4, 4), dtype=np.uint8)
    image: Any = TYPESTORE.deserialize_cdr(encode_image_cdr(pixels, "bgra8"), IMAGE_TYPE)
    types = TYPESTORE.types
    image.header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
    )
    return bytes(TYPESTORE.serialize_cdr(image, IMAGE_TYPE))


def _equals(get: Callable[[], int], value: int) -> bool:
    return get() == value


def test_unbounded_seq_long_frame_ids_and_bad_nanosec_are_rejected(endpoint: str) -> None:
    pixels = np.zeros((4, 4, 4), dtype=np.uint8).tobytes()
    long_id = "f" * 300
    bad: list[tuple[bytes, bytes | None, str]] = [
        (pixels, msgpack.packb({"width": 4, "height": 4, "seq": 2**64 - 1}), "bad_attachment"),
        (pixels, msgpack.packb({"width": 4, "height": 4, "frame_id": long_id}), "bad_attachment"),
        (_cdr_frame(frame_id=long_id), None, "bad_cdr"),
        (_cdr_frame(nanosec=1_000_000_000), None, "bad_stamp"),
    ]
    with (
        running_cli("run", "-l", endpoint, "--no-multicast-scouting", "--stats-interval-s", "0"),
        open_session(connect=[endpoint]) as camera,
    ):
        wait_for_status(camera)
        records = Collector(camera, "perception/tags")
        frames = camera.declare_publisher(FRAMES, congestion_control=_BLOCK)
        wait_for_subscriber(frames)

        def rejected() -> int:
            status = query_status(camera)
            return -1 if status is None else int(status["frames"]["rejected"])

        for count, (payload, attachment, _reason) in enumerate(bad, start=1):
            frames.put(payload, attachment=attachment)  # one at a time: none dropped
            wait_until(partial(_equals, rejected, count), what=f"rejection {count}")
        status = query_status(camera)
        assert status is not None
        assert status["rejected_by_reason"] == {"bad_attachment": 2, "bad_cdr": 1, "bad_stamp": 1}
        assert records.drain() == []


@pytest.mark.parametrize("keys", [('"3"', '"03"'), ('"3"', '" 3"'), ('"+3"',)])
def test_tag_sizes_with_a_duplicate_or_non_canonical_id_exit_2(
    tmp_path: Path, keys: tuple[str, ...]
) -> None:
    settings = tmp_path / "perception.toml"
    table = ", ".join(f"{key} = 0.{i + 1}" for i, key in enumerate(keys))
    settings.write_text(f"tag_sizes = {{ {table} }}\n", encoding="utf-8")
    result = run_cli("run", "--settings", str(settings), "--no-multicast-scouting", timeout=30)
    assert result.returncode == 2, result.stderr
    assert "tag_sizes" in result.stderr
    assert "Traceback" not in result.stderr


_NO_PEERS = ("--no-multicast-scouting",)


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("demo", "--fps", "0.04"), "--fps"),
        (("demo", "--fps", "nan"), "--fps"),
        (("demo", "--fps", "inf"), "--fps"),
        (("demo", "--limit", "9" * 400), "--limit"),
        (("status", "--timeout", "inf"), "--timeout"),
        (("echo", "--timeout", "nan"), "--timeout"),
        (("echo", "--tag-key", "a//b"), "--tag-key"),
        (("echo", "--record-key", "a//b"), "--record-key"),
        (("status", "--status-key", "a//b"), "--status-key"),
        (("replay", "{images}", "--rate", "1e-300"), "--rate"),
        (("replay", "{images}", "--key", "**"), "--key"),
        (("replay", "{images}", "--key", "a//b"), "--key"),
        (("replay", "{images}", "--frame-id", "f" * 300), "--frame-id"),
        (("bench", "--seed", "-1"), "--seed"),
        (("run", "--max-frame-pixels", "9" * 400), "max_frame_pixels"),
        (("run", "--camera-fx", "9" * 400), "camera_fx"),
    ],
)
def test_a_bad_flag_is_one_line_naming_it_and_exit_2(
    tmp_path: Path, args: tuple[str, ...], named: str
) -> None:
    images = tmp_path / "images"
    images.mkdir()
    cv2.imwrite(str(images / "a.png"), np.zeros((8, 8, 3), dtype=np.uint8))
    argv = [arg.replace("{images}", str(images)) for arg in args]
    result = run_cli(*argv, *_NO_PEERS, timeout=30)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and named in errors[0], result.stderr


@pytest.mark.parametrize(
    ("text", "named"),
    [
        (f"camera_fx = {'9' * 400}\n", "camera_fx"),
        (f"max_frame_bytes = {'9' * 400}\n", "max_frame_bytes"),
        (f"max_frame_bytes = {'9' * 5000}\n", "perception.toml"),
        ("x = " + "[" * 5000 + "]" * 5000 + "\n", "perception.toml"),
    ],
)
def test_a_bad_settings_file_is_one_line_naming_it_and_exit_2(
    tmp_path: Path, text: str, named: str
) -> None:
    settings = tmp_path / "perception.toml"
    settings.write_text(text, encoding="utf-8")
    result = run_cli("run", "--settings", str(settings), *_NO_PEERS, timeout=30)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and named in errors[0], result.stderr


def _replay(path: Path, endpoint: str, *extra: str) -> subprocess.CompletedProcess[str]:
    return run_cli(
        "replay",
        str(path),
        "-e",
        endpoint,
        "--no-multicast-scouting",
        "--subscriber-timeout",
        "30",
        *extra,
        timeout=60,
    )


def test_replay_cuts_a_forward_jump_of_the_recording_clock(tmp_path: Path, endpoint: str) -> None:
    bag = tmp_path / "jump"
    pixels = np.zeros((4, 4, 4), dtype=np.uint8)
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        images = writer.add_connection("/zed/left/image", IMAGE_TYPE, typestore=TYPESTORE)
        for index, received in enumerate((10**9, 2**63 - 10**9)):  # then ~292 years later
            frame = bytes(encode_image_cdr(pixels, "bgra8", stamp_ns=index + 1, frame_id="c"))
            writer.write(images, received, frame)
    with open_session(listen=[endpoint]) as service:
        frames = Collector(service, FRAMES)
        result = _replay(bag, endpoint)
        assert result.returncode == 0, result.stderr
        assert len(frames.drain()) == 2
    (capped,) = log_events(result.stderr, "replay_gap_capped")
    assert float(capped["gap_s"]) > 9e9
    assert float(capped["waited_s"]) <= 5


def _video(path: Path) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 30.0, (64, 48))
    assert writer.isOpened()
    try:
        for index in range(30):
            writer.write(np.full((48, 64, 3), index * 8, dtype=np.uint8))
    finally:
        writer.release()


def test_replay_says_what_a_truncated_video_did_not_send(tmp_path: Path, endpoint: str) -> None:
    video = tmp_path / "truncated.avi"
    _video(video)
    data = video.read_bytes()
    video.write_bytes(data[: len(data) * 7 // 10])  # OpenCV reads 15 of its 30 frames
    with open_session(listen=[endpoint]) as service:
        frames = Collector(service, FRAMES)
        result = _replay(video, endpoint, "--as-fast-as-possible")
        sent = len(frames.drain())
    assert result.returncode == 0, result.stderr
    assert 0 < sent < 30
    (incomplete,) = log_events(result.stderr, "replay_incomplete")
    assert (int(incomplete["published"]), int(incomplete["unsent"])) == (sent, 30 - sent)


def test_replay_of_a_video_with_no_readable_frame_exits_non_zero(
    tmp_path: Path, endpoint: str
) -> None:
    video = tmp_path / "corrupt.avi"
    _video(video)
    data = bytearray(video.read_bytes())
    # keep the headers that announce 30 frames, spoil every frame after them
    start = data.find(b"movi") + 4
    data[start:] = bytes(len(data) - start)
    video.write_bytes(bytes(data))
    with open_session(listen=[endpoint]) as service:
        Collector(service, FRAMES)
        result = _replay(video, endpoint, "--as-fast-as-possible")
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    assert "sent no frame" in result.stderr


def _huge_grey_png(side: int) -> bytes:
    """A valid PNG of side x side black pixels: a few hundred KB that decode to side**2 B."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    compressor = zlib.compressobj(9)
    row = bytes(1 + side)  # filter byte, then grey pixels
    idat = b"".join(compressor.compress(row) for _ in range(side)) + compressor.flush()
    ihdr = struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_replay_refuses_an_image_by_its_declared_size_before_decoding(
    tmp_path: Path, endpoint: str
) -> None:
    folder = tmp_path / "images"
    folder.mkdir()
    (folder / "huge.png").write_bytes(_huge_grey_png(16000))
    with open_session(listen=[endpoint]) as service:
        Collector(service, FRAMES)
        result = _replay(folder, endpoint)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "huge.png" in errors[0] and "16000x16000" in errors[0]


def test_replay_of_a_bit_flipped_bag_is_one_line_and_exit_2(tmp_path: Path, endpoint: str) -> None:
    bag = tmp_path / "flipped.mcap"
    pixels = np.zeros((4, 4, 4), dtype=np.uint8)
    folder = tmp_path / "bag"
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        images = writer.add_connection("/zed/left/image", IMAGE_TYPE, typestore=TYPESTORE)
        for index in range(3):
            frame = bytes(encode_image_cdr(pixels, "bgra8", stamp_ns=index + 1, frame_id="c"))
            writer.write(images, 10**9 + index, frame)
    data = bytearray(next(folder.glob("*.mcap")).read_bytes())
    # magic (8 bytes), the header record's opcode (1) and length (8): a flipped top bit of
    # that length claims 2**62 bytes, which rosbags tries to read at once
    data[16] ^= 0x40
    bag.write_bytes(bytes(data))
    with open_session(listen=[endpoint]) as service:
        Collector(service, FRAMES)
        result = _replay(bag, endpoint)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "flipped.mcap" in errors[0]


def test_replay_of_a_bag_with_deeply_nested_metadata_is_one_line_and_exit_2(
    tmp_path: Path, endpoint: str
) -> None:
    folder = tmp_path / "deep"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: " + "[" * 50_000)
    with open_session(listen=[endpoint]) as service:
        Collector(service, FRAMES)
        result = _replay(folder, endpoint)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "nested 50000 levels deep" in errors[0]
