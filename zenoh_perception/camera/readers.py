"""Why a camera's frames have no reader: the input keys of the services on the network.

A camera waiting for a subscriber asks ``perception/status`` who runs, and says which input
keys those services read when none of them matches the camera's key (a ``*`` matches one
chunk: ``rover/*/image`` reads ``rover/front/image``, not ``rover/front/camera/image``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

import zenoh

from zenoh_perception.service.logs import kv
from zenoh_perception.service.status import query_status

#: The services' status key (their default ``status_key``).
STATUS_KEY: Final = "perception/status"
#: Seconds given to the services to answer one status query.
ANSWER_S: Final = 1.0
#: The settings naming what a service reads.
_INPUTS: Final = ("input_key", "compressed_input_key")


def service_inputs(statuses: Sequence[dict[str, Any]]) -> list[str]:
    """Every input key expression of the services whose status is in ``statuses``, once each,
    in order."""
    found: list[str] = []
    for status in statuses:
        settings = status.get("settings")
        if not isinstance(settings, dict):
            continue
        for name in _INPUTS:
            value = settings.get(name)
            entries = [value] if isinstance(value, str) else value
            if not isinstance(entries, list):
                continue
            found += [e for e in entries if isinstance(e, str) and e and e not in found]
    return found


def waiting_fields(key: str, statuses: Sequence[dict[str, Any]]) -> str:
    """The ``key=value`` fields of a camera's waiting line: who answered, what they read, and
    what to do."""
    inputs = service_inputs(statuses)
    if not statuses:
        detail = (
            f"no perception service answered on {STATUS_KEY}: is one running, and do both "
            "sides meet (the same -e/-l, or multicast scouting allowed)?"
        )
    elif any(zenoh.KeyExpr(key).intersects(zenoh.KeyExpr(i)) for i in inputs):
        detail = "a service reads this key but has not subscribed yet (a share group's member?)"
    else:
        detail = (
            "no service's input matches this key ('*' matches one chunk, '**' several): "
            "publish on a key one of them reads, or give a service an --input-key matching it"
        )
    return kv(services=len(statuses), their_inputs=",".join(inputs), detail=detail)


def ask(session: zenoh.Session, timeout_s: float = ANSWER_S) -> list[dict[str, Any]]:
    """The status of every service that answers within ``timeout_s``."""
    return query_status(session, STATUS_KEY, timeout_s, gather=False)
