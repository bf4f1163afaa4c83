"""Shared test helpers: in-process Zenoh peers on free loopback ports, collectors, the CLI.

Every session opened here is multicast-scouting-free and listens/connects on 127.0.0.1 only.
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from zenoh_perception.detect.types import Detector
from zenoh_perception.pipeline import Pipeline
from zenoh_perception.settings import Settings
from zenoh_perception_bench._loopback import free_port, loopback_config, loopback_endpoint

REPO = Path(__file__).resolve().parent.parent
#: How long a test waits, by default, for something that should come: generous, since it
#: costs nothing when the thing comes early, and a 2-core machine running two test suites
#: and more may give a process a tenth of a core for seconds.
WAIT_S = 60.0


@contextmanager
def open_session(
    *, mode: str = "peer", listen: Sequence[str] = (), connect: Sequence[str] = ()
) -> Iterator[zenoh.Session]:
    """A Zenoh session that is always closed, whatever the test does."""
    session = zenoh.open(loopback_config(mode=mode, listen=listen, connect=connect))
    try:
        yield session
    finally:
        session.close()


@dataclass(frozen=True)
class Received:
    key: str
    payload: bytes
    encoding: str
    attachment: bytes | None


class Collector:
    """Subscribes to a key and queues every sample for the test to wait on."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.queue: queue.Queue[Received] = queue.Queue()
        self._subscriber = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment
        self.queue.put(
            Received(
                str(sample.key_expr),
                sample.payload.to_bytes(),
                str(sample.encoding),
                None if attachment is None else attachment.to_bytes(),
            )
        )

    def get(self, timeout: float = WAIT_S) -> Received:
        """The next sample; raises queue.Empty after ``timeout`` s."""
        return self.queue.get(timeout=timeout)

    def drain(self) -> list[Received]:
        items: list[Received] = []
        while True:
            try:
                items.append(self.queue.get_nowait())
            except queue.Empty:
                return items

    def undeclare(self) -> None:
        self._subscriber.undeclare()


def wait_for_subscriber(publisher: zenoh.Publisher, timeout: float = WAIT_S) -> None:
    """Block until ``publisher`` has a matching subscriber (or fail after ``timeout``)."""
    matched: queue.Queue[bool] = queue.Queue()
    listener = publisher.declare_matching_listener(lambda status: matched.put(status.matching))
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if matched.get(timeout=max(0.0, deadline - time.monotonic())):
                    return
            except queue.Empty:
                break
        msg = f"no subscriber matched {publisher.key_expr} within {timeout} s"
        raise TimeoutError(msg)
    finally:
        listener.undeclare()


def query_status(
    session: zenoh.Session, key: str = "perception/status", timeout: float = 1.0
) -> dict[str, Any] | None:
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None:
            data: dict[str, Any] = json.loads(reply.ok.payload.to_string())
            return data
    return None


def wait_for_status(
    session: zenoh.Session, key: str = "perception/status", timeout: float = WAIT_S
) -> dict[str, Any]:
    """Poll the status queryable until a service answers (it is then fully started)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = query_status(session, key, timeout=0.5)
        if status is not None:
            return status
    msg = f"no service answered on {key} within {timeout} s"
    raise TimeoutError(msg)


def cli_command(*args: str) -> list[str]:
    """The real ``zenoh-perception`` CLI, run with this interpreter."""
    return [sys.executable, "-m", "zenoh_perception", *args]


def sigterm_exit(proc: subprocess.Popen[str], timeout: float = 10.0) -> tuple[int, float]:
    """SIGTERM ``proc`` and wait for it: its exit code and the seconds the exit took (the
    test fails when it does not exit within ``timeout``)."""
    started = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"no exit within {timeout:g} s of SIGTERM")
    return code, time.monotonic() - started


@contextmanager
def running_cli(
    *args: str, stop_timeout: float = 30.0, cwd: Path = REPO
) -> Iterator[subprocess.Popen[str]]:
    """Start the real CLI as a subprocess in ``cwd``; SIGINT and reap it on exit (kill if it
    hangs: a test that checks the exit code after the block then sees -9)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        cli_command(*args),
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=stop_timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


class OutputLines:
    """The output lines of a subprocess, read on a thread so that a test can wait for one line
    with a deadline (a plain ``for line in proc.stdout`` blocks for ever when it never comes)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        self.seen: list[str] = []
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._thread = threading.Thread(target=self._read, args=(proc.stdout,), daemon=True)
        self._thread.start()

    def _read(self, stream: Iterator[str]) -> None:
        try:
            for line in stream:
                self._lines.put(line)
        except (ValueError, OSError):  # the stream was closed under the reader
            pass
        finally:
            self._lines.put(None)  # end of output

    def wait_for(self, text: str, timeout: float = WAIT_S) -> str:
        """The next line holding ``text``; AssertionError at the end of the output, TimeoutError
        when no such line came within ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            line = self._next(deadline, f"no line with {text!r} within {timeout} s")
            if line is None:
                msg = f"{text!r} not in the output:\n{''.join(self.seen)}"
                raise AssertionError(msg)
            if text in line:
                return line

    def rest(self, timeout: float = WAIT_S) -> list[str]:
        """Every line still to come, up to the end of the output (the process has exited or
        is exiting); TimeoutError when the output has not ended within ``timeout`` s."""
        deadline = time.monotonic() + timeout
        rest: list[str] = []
        while (
            line := self._next(deadline, f"the output did not end within {timeout} s")
        ) is not None:
            rest.append(line)
        return rest

    def _next(self, deadline: float, late: str) -> str | None:
        """The next line (kept in ``seen``), None at the end of the output; TimeoutError with
        ``late`` and the output so far when none came before ``deadline``."""
        try:
            line = self._lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            msg = f"{late}:\n{''.join(self.seen)}"
            raise TimeoutError(msg) from None
        if line is not None:
            self.seen.append(line)
        return line


def wait_until(
    predicate: Callable[[], bool], timeout: float = WAIT_S, what: str = "condition"
) -> None:
    """Poll ``predicate`` (every 10 ms) until it holds; TimeoutError after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    pause = threading.Event()
    while not predicate():
        if time.monotonic() >= deadline:
            msg = f"{what} not reached within {timeout} s"
            raise TimeoutError(msg)
        pause.wait(0.01)


_KEY = r"[A-Za-z_][A-Za-z0-9_.]*"
_VALUE = r'(?:"(?:[^"\\\n]|\\.)*"|[^\s"]*)'
#: A whole log line of key=value pairs, values bare or JSON-quoted.
KEY_VALUE_LINE = re.compile(rf"{_KEY}={_VALUE}(?: {_KEY}={_VALUE})*")
_PAIR = re.compile(rf"({_KEY})=({_VALUE})")


def parse_pairs(line: str) -> dict[str, str]:
    """The key=value pairs of a log line (values unquoted); lenient about what lies between."""
    return {key: value.strip('"') for key, value in _PAIR.findall(line)}


def log_events(output: str, event: str) -> list[dict[str, str]]:
    """The key=value pairs of each line of ``output`` that logs ``event=<event>``."""
    found = (parse_pairs(line) for line in output.splitlines())
    return [pairs for pairs in found if pairs.get("event") == event]


def run_cli(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """Run the real CLI to completion and capture its output (never raises on exit codes)."""
    return subprocess.run(
        cli_command(*args),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


# the loopback helpers are the benchmarks' own (one implementation), re-exported for the tests
__all__ = ["free_port", "loopback_config", "loopback_endpoint"]


def json_objects(text: str) -> list[dict[str, object]]:
    """Every JSON object printed in ``text`` (pretty-printed ones included), in order."""
    decoder = json.JSONDecoder()
    objects, index = [], 0
    while (index := text.find("{", index)) != -1:
        value, index = decoder.raw_decode(text, index)
        objects.append(value)
    return objects


#: Settings of a service with a stream per camera: ``cams/<name>/image`` answered on
#: ``cams/<name>/...``.
STREAMS = Settings.from_flat(
    stats_interval_s=0,
    input_key="cams/*/image",
    compressed_input_key="",
    tag_key="cams/{stream}/tag",
    record_key="cams/{stream}/perception/tags",
    debug_image_key="cams/{stream}/debug",
    detections_key="cams/{stream}/detections",
)


def pipeline_of(settings: Settings, detector: Detector | None = None) -> Pipeline:
    """The pipeline the service builds for ``settings`` (its detection and selection)."""
    return Pipeline(settings.detection, settings.selection, detector)
