"""Log lines in ``key=value`` form, safe against whatever text a payload carries.

Every line is ``ts=<ISO 8601 UTC> level=<LEVEL> logger=<name>`` followed by the message's own
``key=value`` pairs. Values that are not plain tokens are JSON-quoted (quotes, backslashes,
newlines and every other control character escaped), so a hostile string from the network can
neither break a line in two, nor forge a key, nor reach a terminal as an escape sequence. The
formatter escapes whatever control character is left in a line (a library's own message).
"""

from __future__ import annotations

import json
import logging
import re
import sys
import threading
import time
from collections.abc import Callable
from typing import Final, Protocol

_PLAIN: Final = re.compile(r"[^\s\"=\\\x00-\x1f\x7f-\x9f]*")
#: C0 controls, DEL and C1 controls: what a terminal may act on.
_CONTROL: Final = re.compile(r"[\x00-\x1f\x7f-\x9f]")
log = logging.getLogger("zenoh_perception.service.logs")


def kv_value(value: object) -> str:
    """``value`` as a key=value value: bare when it is a plain token, JSON-quoted otherwise."""
    text = value if isinstance(value, str) else str(value)
    if text and _PLAIN.fullmatch(text):
        return text
    # json escapes C0 controls and, ASCII-only, everything past DEL; DEL itself stays raw
    return json.dumps(text).replace("\x7f", "\\u007f")


def escape_controls(text: str) -> str:
    """``text`` with each control character written as an escape (``\\n``, ``\\x1b``)."""
    return _CONTROL.sub(_escape_one, text)


def _escape_one(match: re.Match[str]) -> str:
    char = match.group()
    return "\\n" if char == "\n" else f"\\x{ord(char):02x}"


def kv(**fields: object) -> str:
    """``a=1 b="two words"`` from keyword arguments, in order."""
    return " ".join(f"{key}={kv_value(value)}" for key, value in fields.items())


class KeyValueFormatter(logging.Formatter):
    """``ts=... level=... logger=... <message>``; exceptions become one quoted ``exc=``."""

    def format(self, record: logging.LogRecord) -> str:
        seconds = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        millis = int(record.msecs)
        line = (
            f"ts={seconds}.{millis:03d}Z level={record.levelname} logger={record.name} "
            f"{record.getMessage()}"
        )
        if record.exc_info:
            line += f" exc={kv_value(self.formatException(record.exc_info))}"
        return escape_controls(line)


def _log_thread_crash(args: threading.ExceptHookArgs) -> None:
    name = args.thread.name if args.thread is not None else "unknown"
    log.error(
        "event=thread_crashed %s",
        kv(thread=name, error=args.exc_type.__name__),
        exc_info=args.exc_value,
    )


def configure_logging(level: str = "INFO") -> None:
    """Send key=value lines at ``level`` to stderr (replacing earlier handlers); a crashing
    thread is logged as ``event=thread_crashed`` instead of a raw traceback."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(KeyValueFormatter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
    threading.excepthook = _log_thread_crash


class Admits(Protocol):
    """A rate limit by key (:class:`~zenoh_perception.service.stats.LogGate`)."""

    def admit(self, key: str) -> int | None: ...


class LimitedLog:
    """The one way a repeating line is logged: ``event`` at most once per the ``gate``'s
    interval for ``key``, saying how many lines were left out since the last one, with what
    ``about`` returns (the stream a line is about) first among its fields."""

    def __init__(
        self,
        logger: logging.Logger,
        gate: Admits,
        about: Callable[[], dict[str, str]] = dict,
    ) -> None:
        self._logger = logger
        self._gate = gate
        self._about = about

    def __call__(self, level: int, key: str, event: str, /, **fields: object) -> None:
        suppressed = self._gate.admit(key)
        if suppressed is not None:
            line = kv(**self._about(), **fields, suppressed=suppressed)
            self._logger.log(level, "event=%s %s", event, line)
