"""SIGINT and SIGTERM as the stop event of every long-running command, and leave(): how such a
command's process ends."""

from __future__ import annotations

import signal
import subprocess
import sys
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


# A process whose daemon thread is inside OpenCV, coming back for the GIL between calls, as the
# service's worker or an abandoned read is: the interpreter's finalization unwinds that thread
# by force through OpenCV's catch-all C++ code (SIGABRT) where leave() does not finalize.
_BUSY_IN_OPENCV = """
import atexit, logging, sys, threading
import cv2
import numpy as np
from zenoh_perception.service.logs import configure_logging
from zenoh_perception.service.signals import leave

y, x = np.indices((720, 1280))
board = np.asarray(((x // 10 + y // 10) % 2) * 255, dtype=np.uint8)

def busy():
    while True:
        cv2.GaussianBlur(board, (31, 31), 0)

threading.Thread(target=busy, daemon=True).start()
configure_logging("INFO")
atexit.register(print, "atexit ran", file=sys.stderr)
logging.getLogger("zenoh_perception.test").info("event=stopped")
print("stdout written")
sys.stdout.write("unterminated")
"""


def _python(program: str, *, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", program],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.mark.parametrize("code", [0, 1, 2])
def test_leave_exits_with_its_code_under_a_thread_inside_opencv(code: int) -> None:
    done = _python(f"{_BUSY_IN_OPENCV}\nleave({code})")
    assert done.returncode == code, done.stderr
    # what a normal exit writes is written: the log, the atexit handlers, unflushed stdout
    assert done.stdout.splitlines() == ["stdout written", "unterminated"]
    assert "event=stopped" in done.stderr and "atexit ran" in done.stderr
    assert "terminate" not in done.stderr and "FATAL" not in done.stderr


def test_leave_waits_for_non_daemon_threads_within_its_time() -> None:
    program = """
import threading
from zenoh_perception.service.signals import leave

go = threading.Event()

def short():
    go.wait()
    print("short thread ended", flush=True)

threading.Thread(target=short).start()
threading.Thread(target=threading.Event().wait).start()  # one that never ends
go.set()  # the short thread ends by itself, soon: leave() waits for it
try:
    leave(0, join_s=2.0)
finally:
    print("not reached")
"""
    done = _python(program)
    assert done.returncode == 0, done.stderr
    # the never-ending thread held the exit up for join_s at most: the process was ended
    # (os._exit) rather than waiting for it as the interpreter would, for ever
    assert done.stdout.splitlines() == ["short thread ended"]
