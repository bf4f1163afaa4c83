"""Asking running services for their status: the client side of the status queryable."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import zenoh


def query_status(
    session: zenoh.Session,
    key: str = "perception/status",
    timeout: float = 2.0,
    *,
    gather: bool = True,
) -> list[dict[str, Any]]:
    """Every service's status reply, one per service.

    With ``gather`` the query is repeated until ``timeout`` (s) is over: a peer discovered
    late, or whose queryable was not known yet when the first query went out, still answers.
    Without it, the replies to one query (a poll that will ask again).
    """
    deadline = time.monotonic() + timeout
    by_service: dict[str, dict[str, Any]] = {}
    while (left := deadline - time.monotonic()) > 0:
        # every service answers on the same key: without consolidation none of them is
        # dropped as a duplicate of another's reply
        replies = session.get(key, timeout=left, consolidation=zenoh.ConsolidationMode.NONE)
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                data = json.loads(reply.ok.payload.to_string())
            except ValueError:
                continue
            if isinstance(data, dict):
                by_service[str(data.get("zid", len(by_service)))] = data
        if not gather:
            break
        # a query that nobody could answer returns at once: do not spin
        threading.Event().wait(min(REQUERY_S, max(0.0, deadline - time.monotonic())))
    return list(by_service.values())


#: Pause between two queries of :func:`query_status`.
REQUERY_S = 0.1
