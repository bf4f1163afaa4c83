"""Asking running services for their status: the client side of the status queryable."""

from __future__ import annotations

import threading
import time
from collections import Counter
from typing import Any

import zenoh

from zenoh_perception.errors import JsonPayloadError
from zenoh_perception.wire.bounded_json import MAX_JSON_BYTES, loads_bounded


def query_status(
    session: zenoh.Session,
    key: str = "perception/status",
    timeout: float = 2.0,
    *,
    gather: bool = True,
    skipped: Counter[str] | None = None,
) -> list[dict[str, Any]]:
    """Every service's status reply, one per service.

    A reply that is no status (over :data:`MAX_JSON_BYTES`, not JSON, nested too deep, NaN or
    Infinity in it, not an object) is left out and counted by reason in ``skipped``: one rogue
    peer on the key hides no service.

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
            payload = reply.ok.payload
            try:
                if len(payload) > MAX_JSON_BYTES:  # before the copy out of Zenoh
                    raise JsonPayloadError("too_large", f"{len(payload)} bytes")
                data = loads_bounded(payload.to_bytes())
            except JsonPayloadError as err:
                if skipped is not None:
                    skipped[err.reason] += 1
                continue
            if isinstance(data, dict):
                by_service[str(data.get("zid", len(by_service)))] = data
            elif skipped is not None:
                skipped["not_an_object"] += 1
        if not gather:
            break
        # a query that nobody could answer returns at once: do not spin
        threading.Event().wait(min(REQUERY_S, max(0.0, deadline - time.monotonic())))
    return list(by_service.values())


#: Pause between two queries of :func:`query_status`.
REQUERY_S = 0.1
