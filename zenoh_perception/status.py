"""``zenoh-perception status``: query the service's status queryable and print its JSON."""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any, TextIO

import zenoh

from zenoh_perception.zenoh_args import open_zenoh


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
        for reply in session.get(key, timeout=left):
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


def main(
    conf: zenoh.Config,
    *,
    key: str = "perception/status",
    timeout: float = 2.0,
    out: TextIO = sys.stdout,
) -> int:
    """Print the status JSON; 0 when at least one service answered, 1 otherwise.

    Raises:
        SessionError: the Zenoh session cannot be opened.

    """
    with open_zenoh(conf) as session:
        replies = query_status(session, key, timeout)
    if not replies:
        print(f"no perception service answered on {key!r} within {timeout} s", file=sys.stderr)
        return 1
    for reply in replies:
        print(json.dumps(reply, indent=2), file=out)
    return 0
