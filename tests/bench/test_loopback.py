"""Free loopback ports for Zenoh peers started apart from each other (tests in parallel)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from zenoh_perception_bench import _loopback
from zenoh_perception_bench._loopback import free_port, loopback_endpoint


def _bindable(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def test_ports_come_from_below_the_ephemeral_range_and_are_free() -> None:
    low = _loopback._ephemeral_low()
    ports = {free_port() for _ in range(50)}
    assert all(max(1024, low - _loopback._SPAN) <= port < low for port in ports)
    assert len(ports) > 40  # chosen at random: two choosers rarely meet
    assert all(_bindable(port) for port in ports)
    assert loopback_endpoint().startswith("tcp/127.0.0.1:")


def test_a_port_in_use_is_not_chosen(monkeypatch: pytest.MonkeyPatch) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        taken = busy.getsockname()[1]
        busy.listen()
        offered = iter([taken, taken, taken + 1 if taken < 65535 else taken - 1])
        monkeypatch.setattr("random.randrange", lambda *_: next(offered))
        monkeypatch.setattr(_loopback, "_ephemeral_low", lambda: 65536)
        assert free_port() != taken


def test_without_room_below_the_range_the_kernel_chooses(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    ranges = tmp_path / "ip_local_port_range"
    ranges.write_text("1500\t60999\n", encoding="ascii")
    monkeypatch.setattr(_loopback, "_PORT_RANGE", ranges)
    assert _loopback._ephemeral_low() == 1500
    assert free_port() >= 1024
    monkeypatch.setattr(_loopback, "_PORT_RANGE", tmp_path / "missing")
    assert _loopback._ephemeral_low() == 32768
