"""Closing the service's session: bounded, so that a stop under a token flood exits promptly."""

from __future__ import annotations

import threading

import pytest
import zenoh

from tests.helpers import loopback_config
from zenoh_perception.service.session import close_within


class _StuckSession:
    """A session whose close never returns until released (Zenoh's close under a flood)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.closing = threading.Event()

    def close(self) -> None:
        self.closing.set()
        self.release.wait()


def test_a_close_that_hangs_is_left_behind_after_the_wait(caplog: pytest.LogCaptureFixture) -> None:
    stuck = _StuckSession()
    try:
        assert close_within(stuck, timeout_s=0.05) is False  # type: ignore[arg-type]
        assert stuck.closing.is_set()
        assert "event=session_close_slow" in caplog.text
    finally:
        stuck.release.set()


def test_a_real_session_closes_within_the_wait() -> None:
    session = zenoh.open(loopback_config())
    assert close_within(session) is True
    assert session.is_closed()
