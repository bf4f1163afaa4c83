"""Observability of the real service (CLI subprocess): status JSON, liveliness, key=value logs.

Bad payloads are sent one at a time, each awaited in the status counters, so none is dropped by
the latest-frame-wins mailbox and every count below is exact.
"""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import msgpack
import pytest
import zenoh

from tests.helpers import (
    KEY_VALUE_LINE,
    Collector,
    open_session,
    parse_pairs,
    query_status,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tools.rig import marker_frame, raw_attachment
from zenoh_perception.settings import Settings
from zenoh_perception.wire.records import decode_record

FRAMES = "zed/left/image"
_BLOCK = zenoh.CongestionControl.BLOCK

# One malformed payload per rejection reason: (payload, attachment).
_BAD: dict[str, tuple[bytes, bytes | None]] = {
    "bad_cdr": (b"\x00\x01\x00\x00garbage", None),
    "bad_attachment": (b"\x00" * 4, b"\xc1"),
    "unsupported_encoding": (
        b"\x00" * 4,
        msgpack.packb({"width": 1, "height": 1, "encoding": 'say "hi"\nlevel=ERROR'}),
    ),
    "bad_dimensions": (b"\x00" * 4, msgpack.packb({"width": -1, "height": 1})),
    "size_mismatch": (b"\x00" * 3, msgpack.packb({"width": 1, "height": 1})),
}


class Camera:
    """A raw-frame publisher plus the service's records, for one probe session."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        # BLOCK: a large frame is never dropped by Zenoh when the machine is busy.
        self.publisher = session.declare_publisher(FRAMES, congestion_control=_BLOCK)
        self.records = Collector(session, "perception/tags")
        wait_for_subscriber(self.publisher)

    def good(self, seq: int, tag_id: int = 4) -> dict[str, Any]:
        frame = marker_frame(320, 240, tag_id, side=96)
        self.publisher.put(frame.payload, attachment=raw_attachment(320, 240, seq=seq))
        while True:
            try:
                record = decode_record(self.records.get(timeout=30.0).payload)
            except queue.Empty:
                status = query_status(self.session, timeout=2.0)
                pytest.fail(
                    f"frame {seq} not answered; service frames: {status and status['frames']}"
                )
            if record["seq"] == seq:
                return record

    def bad(self, reason: str) -> None:
        """Send the malformed payload for ``reason`` and wait until the service counted it."""
        before = self.rejected(reason)
        payload, attachment = _BAD[reason]
        self.publisher.put(payload, attachment=attachment)
        wait_until(lambda: self.rejected(reason) > before, what=f"a {reason} rejection")

    def rejected(self, reason: str) -> int:
        status = query_status(self.session, timeout=2.0)
        return 0 if status is None else int(status["rejected_by_reason"].get(reason, 0))

    def close(self) -> None:
        self.records.undeclare()
        self.publisher.undeclare()


def _service_args(endpoint: str, *extra: str) -> tuple[str, ...]:
    return ("run", "-l", endpoint, "--no-multicast-scouting", *extra)


def test_status_is_json_with_counters_rates_latency_and_effective_settings(endpoint: str) -> None:
    flags = ("--policy", "center", "--stats-interval-s", "0", "--log-interval-s", "30")
    with (
        running_cli(*_service_args(endpoint, *flags)),
        open_session(connect=[endpoint]) as probe,
    ):
        first = wait_for_status(probe)
        camera = Camera(probe)
        for seq in range(3):
            assert camera.good(seq)["selected"]["tag_id"] == 4
        for reason in _BAD:
            camera.bad(reason)
        camera.bad("bad_cdr")
        camera.close()
        replies = [r.ok for r in probe.get("perception/status", timeout=5.0) if r.ok is not None]
    assert len(replies) == 1
    assert str(replies[0].encoding) == "application/json"
    status = json.loads(replies[0].payload.to_string())
    assert status["uptime_s"] > first["uptime_s"] >= 0
    assert status["frames"] == {"received": 9, "processed": 3, "dropped": 0, "rejected": 6}
    assert status["rejected_by_reason"] == {reason: 1 for reason in _BAD} | {"bad_cdr": 2}
    assert status["fps"] > 0
    latency = status["latency_ms"]
    assert 0 < latency["p50"] <= latency["p99"]
    expected = Settings.from_flat(policy="center", stats_interval_s=0.0, log_interval_s=30.0)
    assert status["settings"] == json.loads(json.dumps(expected.as_dict()))
    assert status["zid"] == first["zid"]


@dataclass
class _Watch:
    """Liveliness samples (kind, key) seen by a subscriber."""

    samples: queue.Queue[tuple[str, str]] = field(default_factory=queue.Queue)

    def __call__(self, sample: zenoh.Sample) -> None:
        self.samples.put((str(sample.kind), str(sample.key_expr)))

    def next_for(self, key: str, timeout: float = 10.0) -> str:
        while True:
            kind, seen = self.samples.get(timeout=timeout)
            if seen == key:
                return kind


def _tokens(session: zenoh.Session) -> set[str]:
    replies = session.liveliness().get("perception/alive/**", timeout=2.0)
    return {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_liveliness_token_is_visible_and_disappears_when_the_service_stops(
    endpoint: str, stop: signal.Signals
) -> None:
    with (
        running_cli(*_service_args(endpoint, "--stats-interval-s", "0")) as proc,
        open_session(connect=[endpoint]) as probe,
    ):
        zid = wait_for_status(probe)["zid"]
        token = f"perception/alive/{zid}"
        assert token in _tokens(probe)
        watch = _Watch()
        subscriber = probe.liveliness().declare_subscriber(
            "perception/alive/**", watch, history=True
        )
        try:
            assert watch.next_for(token) == "SampleKind.PUT"
            proc.send_signal(stop)
            proc.wait(timeout=10.0)
            # Stopped cleanly or killed: either way the others see the token go.
            assert watch.next_for(token) == "SampleKind.DELETE"
        finally:
            subscriber.undeclare()
        assert token not in _tokens(probe)


@dataclass
class _Logs:
    lines: list[str]
    stats_seen: int


@pytest.fixture(scope="module")
def service_logs() -> Iterator[_Logs]:
    """Every log line of one run: started, stats every 0.5 s, rejections, stopped."""
    from tests.helpers import loopback_endpoint

    endpoint = loopback_endpoint()
    flags = ("--stats-interval-s", "0.5", "--log-interval-s", "60")
    lines: queue.Queue[str] = queue.Queue()
    with running_cli(*_service_args(endpoint, *flags)) as proc:
        assert proc.stdout is not None
        stdout = proc.stdout

        def read() -> None:
            for line in stdout:
                lines.put(line)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        with open_session(connect=[endpoint]) as probe:
            wait_for_status(probe)
            camera = Camera(probe)
            camera.good(1)
            for _ in range(5):
                camera.bad("bad_cdr")  # one warning, four suppressed (60 s interval)
            camera.bad("unsupported_encoding")
            camera.close()
        seen: list[str] = []
        stats = 0
        while stats < 2:  # two periodic stats lines after the rejections
            line = lines.get(timeout=10.0)
            seen.append(line)
            if "event=stats " in line and "rejected=6" in line:
                stats += 1
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            pytest.fail("the service did not stop on SIGTERM")
        reader.join(timeout=10.0)
    while not lines.empty():
        seen.append(lines.get_nowait())
    yield _Logs([line.rstrip("\n") for line in seen], stats)


def test_log_has_started_stats_rate_limited_rejections_and_stopped(service_logs: _Logs) -> None:
    events = [parse_pairs(line) for line in service_logs.lines]
    assert all("ts" in e and "level" in e and "event" in e for e in events), service_logs.lines
    started = [e for e in events if e["event"] == "started"]
    assert len(started) == 1
    assert {"version", "zid", "input", "detector", "dictionary", "policy"} <= set(started[0])
    stats = [e for e in events if e["event"] == "stats"]
    assert len(stats) >= 2
    for entry in stats:
        for key in ("received", "processed", "dropped", "rejected"):
            assert entry[key].isdigit()
        for key in ("fps", "latency_p50_ms", "latency_p99_ms"):
            float(entry[key])
    assert stats[-1]["received"] == "7"
    assert stats[-1]["processed"] == "1"
    rejected = [e for e in events if e["event"] == "rejected"]
    # Rate-limited: one line per reason within the 60 s interval, whatever the count.
    assert [(e["reason"], e["level"]) for e in rejected] == [
        ("bad_cdr", "WARNING"),
        ("unsupported_encoding", "WARNING"),
    ]
    stopped = [e for e in events if e["event"] == "stopped"]
    assert len(stopped) == 1
    assert stopped[0]["rejected"] == "6"


def test_every_log_line_is_key_value(service_logs: _Logs) -> None:
    bad = [line for line in service_logs.lines if not KEY_VALUE_LINE.fullmatch(line)]
    assert bad == []
