"""SIGINT / SIGTERM as a stop event, shared by every long-running command."""

from __future__ import annotations

import logging
import signal
import threading

log = logging.getLogger("zenoh_perception.service.signals")


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM; the command then shuts down cleanly with exit 0."""
    stop = threading.Event()

    def handle(signum: int, _frame: object) -> None:
        log.info("event=signal signal=%s", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handle)
    signal.signal(signal.SIGTERM, handle)
    return stop
