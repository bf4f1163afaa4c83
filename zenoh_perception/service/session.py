"""The service's Zenoh session: opening it (retried in client mode), the frame size it can
carry, and whether its connect endpoints reached anyone."""

from __future__ import annotations

import json
import logging
import threading
from typing import Final

import zenoh

from zenoh_perception.errors import SessionError, SettingsError, zenoh_error_text
from zenoh_perception.service.logs import LimitedLog, kv
from zenoh_perception.service.stats import LogGate
from zenoh_perception.settings.sections import Limits

# the service's logger: its lines keep one logger= name, whatever module writes them
log = logging.getLogger(__name__)

#: Zenoh configuration path of the largest message a session accepts.
MAX_MESSAGE_SIZE_PATH: Final = "transport/link/rx/max_message_size"
#: Room a frame message needs besides its payload: the attachment (at most 4 KiB), the key
#: and Zenoh's own headers.
MESSAGE_OVERHEAD_BYTES: Final = 8192
#: Seconds after start at which ``run`` warns that none of its connect endpoints answered.
CONNECT_WARNING_S = 5.0


def open_session(
    conf: zenoh.Config, stop: threading.Event, retry_s: float = 1.0, log_interval_s: float = 5.0
) -> zenoh.Session | None:
    """``zenoh.open(conf)``; in client mode retried every ``retry_s`` until the router is up
    (the retry line is logged at most once per ``log_interval_s``).

    Returns None when ``stop`` is set while waiting.

    Raises:
        SessionError: peer and router modes, at once (e.g. a listen port in use).

    """
    client = json.loads(conf.get_json("mode") or "null") == "client"
    limited = LimitedLog(log, LogGate(log_interval_s))
    while not stop.is_set():
        try:
            return zenoh.open(conf)
        except zenoh.ZError as err:
            text = zenoh_error_text(err)
            if not client:
                msg = f"cannot open the Zenoh session: {text}"
                raise SessionError(msg) from err
            limited(
                logging.WARNING, "connect_failed", "connect_failed", retry_s=retry_s, error=text
            )
            stop.wait(retry_s)
    return None


def check_transport_limit(conf: zenoh.Config, limits: Limits) -> None:
    """Refuse a ``max_frame_bytes`` that the session's own message limit would drop.

    Raises:
        SettingsError: ``max_frame_bytes`` plus the message overhead exceeds Zenoh's
            ``transport/link/rx/max_message_size``.

    """
    try:
        limit = int(json.loads(conf.get_json(MAX_MESSAGE_SIZE_PATH)))
    except (zenoh.ZError, ValueError, TypeError):
        return  # a Zenoh without that setting: nothing to compare with
    if limits.max_frame_bytes + MESSAGE_OVERHEAD_BYTES > limit:
        msg = (
            f"max_frame_bytes = {limits.max_frame_bytes} does not fit Zenoh's "
            f"{MAX_MESSAGE_SIZE_PATH} = {limit} (a frame message needs "
            f"{MESSAGE_OVERHEAD_BYTES} bytes more): lower max_frame_bytes or raise it with "
            f"--cfg '{MAX_MESSAGE_SIZE_PATH}:N' here and on every router in between"
        )
        raise SettingsError(msg)


def connect_endpoints(conf: zenoh.Config) -> list[str]:
    """The endpoints the configuration tells the session to connect to."""
    value = json.loads(conf.get_json("connect/endpoints"))
    if isinstance(value, dict):  # per-mode endpoints
        value = [e for endpoints in value.values() for e in endpoints]
    return [str(e) for e in value] if isinstance(value, list) else []


def session_endpoints(conf: zenoh.Config) -> dict[str, str]:
    """The mode and the endpoints the configuration listens on and connects to, each a
    comma-separated list (for the ``event=started`` line)."""
    found = {}
    for name in ("listen", "connect"):
        value = json.loads(conf.get_json(f"{name}/endpoints"))
        if isinstance(value, dict):  # per-mode endpoints
            value = [e for endpoints in value.values() for e in endpoints]
        found[name] = ",".join(str(e) for e in value) if isinstance(value, list) else ""
    return {"mode": str(json.loads(conf.get_json("mode")) or "peer"), **found}


def warn_if_unlinked(session: zenoh.Session, endpoints: list[str]) -> None:
    """Warn when ``session`` reached no peer or router through ``endpoints`` (yet)."""
    if not _linked(session):
        log.warning(
            "event=unreachable %s",
            kv(
                connect=",".join(endpoints),
                after_s=CONNECT_WARNING_S,
                detail="no peer or router reached through the endpoints to connect "
                "to; Zenoh keeps trying",
            ),
        )


def _linked(session: zenoh.Session) -> bool:
    """Whether the session has reached at least one peer or router."""
    info = session.info
    return bool(list(info.peers_zid()) or list(info.routers_zid()))


#: Seconds the service waits for Zenoh to close its session when it stops.
CLOSE_WAIT_S: Final = 1.0


def close_within(session: zenoh.Session, timeout_s: float = CLOSE_WAIT_S) -> bool:
    """Close ``session``, waiting at most ``timeout_s``; True when the close finished.

    Under a flood of liveliness tokens Zenoh's close can take seconds, and a service that a
    supervisor stops must exit promptly. What a clean close tells the peers, the exit tells
    them too: the process's sockets close with it, and its tokens go at once. The service has
    released its streams and withdrawn its own tokens before this is called.
    """
    closer = threading.Thread(target=session.close, name="zenoh-close", daemon=True)
    closer.start()
    closer.join(timeout_s)
    if closer.is_alive():
        log.warning("event=session_close_slow %s", kv(waited_s=timeout_s))
        return False
    return True
