"""The service's own threads never end silently: one that dies of anything unforeseen says
so (``event=thread_crashed``, with its name and the traceback) and sets the service's
``failed`` event, so that ``run`` exits non-zero and a supervisor restarts the service rather
than leave a liveliness token that claims a service which no longer works."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from zenoh_perception.service.logs import kv

log = logging.getLogger(__name__)


def guarded_thread(
    target: Callable[[], None], *, name: str, failed: threading.Event
) -> threading.Thread:
    """A daemon thread running ``target``; if ``target`` raises, the crash is logged and
    ``failed`` set."""

    def run() -> None:
        try:
            target()
        except Exception as err:  # anything: the point is that no crash goes unseen
            log.exception("event=thread_crashed %s", kv(thread=name, error=repr(err)))
            failed.set()

    return threading.Thread(target=run, name=name, daemon=True)
