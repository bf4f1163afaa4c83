"""``zenoh-perception router``: Zenoh's own router, from zenoh-python, for machines without
``zenohd``.

Nothing of this project runs in it: it is a Zenoh session in router mode, the one ``zenohd``
runs (without zenohd's plugins such as the REST API or storages). It listens where ``-l`` says
(Zenoh's default, ``tcp/[::]:7447``, otherwise), connects to the routers ``-e`` names, prints
its Zenoh id and the locators it listens on, and runs until SIGINT or SIGTERM (exit 0). Its
admin space is on and read-only, as zenohd's is: that is where it reads its own locators.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Mapping
from typing import Final, TextIO

import zenoh

from zenoh_perception.service.session import close_within
from zenoh_perception.service.zenoh_args import open_zenoh

#: What the router sets beside Zenoh's defaults when no ``-c`` file is given.
ROUTER_DEFAULTS: Final[Mapping[str, object]] = {
    "adminspace/enabled": True,
    "adminspace/permissions/read": True,
    "adminspace/permissions/write": False,
}
#: Seconds to wait for the router's own admin-space reply (it answers from the same process).
_ADMIN_TIMEOUT_S: Final = 2.0


def locators(session: zenoh.Session) -> list[str]:
    """The locators ``session`` listens on, as its admin space reports them (wildcard
    addresses resolved to the machine's interfaces); ``[]`` when it does not answer."""
    key = f"@/{session.zid()}/router"
    for reply in session.get(key, timeout=_ADMIN_TIMEOUT_S):
        if reply.ok is None:
            continue
        try:
            found = json.loads(reply.ok.payload.to_string()).get("locators", [])
        except (ValueError, AttributeError):
            return []
        return [str(locator) for locator in found] if isinstance(found, list) else []
    return []


def main(conf: zenoh.Config, stop: threading.Event, out: TextIO) -> int:
    """Run a router with ``conf`` (its mode already ``router``) until ``stop`` is set; 0.

    Raises:
        SessionError: the router cannot start (its port in use, an endpoint that does not
            parse), in one line.

    """
    session = open_zenoh(conf)
    try:
        listening = ", ".join(locators(session)) or conf.get_json("listen/endpoints")
        connecting = conf.get_json("connect/endpoints")
        print(f"router zid={session.zid()} listening on {listening}", file=out)
        if connecting not in ("[]", "null", "{}"):
            print(f"router connecting to {connecting}", file=out)
        print("router running until Ctrl-C (SIGINT) or SIGTERM", file=out, flush=True)
        stop.wait()
    finally:
        # bounded: a router stopped by a supervisor exits promptly even while Zenoh's close
        # lingers over its links (the process's exit closes them anyway)
        close_within(session)
    return 0
