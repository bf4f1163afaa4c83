"""SIGINT and SIGTERM as the stop event of every long-running command."""

from __future__ import annotations

import signal
from collections.abc import Iterator

import pytest

from zenoh_perception.service.signals import stop_on_signals


@pytest.fixture
def restored_handlers() -> Iterator[None]:
    """The process's SIGINT / SIGTERM handlers put back after the test."""
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)


@pytest.mark.usefixtures("restored_handlers")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_the_signal_sets_the_stop_event(
    signum: signal.Signals, caplog: pytest.LogCaptureFixture
) -> None:
    stop = stop_on_signals()
    assert not stop.is_set()
    caplog.set_level("INFO", logger="zenoh_perception")
    signal.raise_signal(signum)  # the handler runs in this (the main) thread, now
    assert stop.is_set()
    assert [r.getMessage() for r in caplog.records] == [f"event=signal signal={signum.name}"]


@pytest.mark.usefixtures("restored_handlers")
def test_each_call_gives_its_own_event_and_the_latest_wins() -> None:
    first, second = stop_on_signals(), stop_on_signals()
    signal.raise_signal(signal.SIGTERM)
    assert second.is_set() and not first.is_set()
