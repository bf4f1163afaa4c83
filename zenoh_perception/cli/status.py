"""``zenoh-perception status``: query the services' status queryable and print their JSON.

One JSON document on stdout: an array with one object per service that answered (``json.load``
reads it whole); with ``lines``, one compact object per line instead (JSON Lines).
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from typing import TextIO

import zenoh

from zenoh_perception.service.status import query_status
from zenoh_perception.service.zenoh_args import open_zenoh


def main(
    conf: zenoh.Config,
    *,
    key: str = "perception/status",
    timeout: float = 2.0,
    lines: bool = False,
    out: TextIO = sys.stdout,
) -> int:
    """Print the statuses (an array, or one object per line with ``lines``); 0 when at least
    one service answered, 1 otherwise. Replies
    that are no status are skipped, and counted by reason on stderr.

    Raises:
        SessionError: the Zenoh session cannot be opened.

    """
    skipped: Counter[str] = Counter()
    with open_zenoh(conf) as session:
        replies = query_status(session, key, timeout, skipped=skipped)
    for reason, count in sorted(skipped.items()):
        print(f"status: skipped {count} reply(ies) on {key!r}: {reason}", file=sys.stderr)
    if not replies:
        print(f"no perception service answered on {key!r} within {timeout} s", file=sys.stderr)
        return 1
    # the replies were parsed without NaN or Infinity: what is printed is JSON
    if lines:
        for reply in replies:
            print(json.dumps(reply, allow_nan=False), file=out)
    else:
        print(json.dumps(replies, indent=2, allow_nan=False), file=out)
    return 0
