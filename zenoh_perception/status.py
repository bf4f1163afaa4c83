"""``zenoh-perception status``: query the service's status queryable and print its JSON."""

from __future__ import annotations

import json
import sys
from typing import Any, TextIO

import zenoh

from zenoh_perception.zenoh_args import open_zenoh


def query_status(
    session: zenoh.Session, key: str = "perception/status", timeout: float = 2.0
) -> list[dict[str, Any]]:
    """Every status reply that arrives within ``timeout`` s (one per running service)."""
    replies: list[dict[str, Any]] = []
    for reply in session.get(key, timeout=timeout):
        if reply.ok is None:
            continue
        try:
            data = json.loads(reply.ok.payload.to_string())
        except ValueError:
            continue
        if isinstance(data, dict):
            replies.append(data)
    return replies


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
