"""The other perception services a service sees under its liveliness key: counted, and a
warning (rate-limited) for each, since two services on the same keys publish every tag and
record twice. A share group's members share the keys by design: they are not counted."""

from __future__ import annotations

import logging
import threading

import zenoh

from zenoh_perception.service.logs import LimitedLog
from zenoh_perception.service.stats import LogGate
from zenoh_perception.settings.sections import Group, Outputs

# the service's logger: its lines keep one logger= name, whatever module writes them
log = logging.getLogger(__name__)


class OtherServices:
    """The liveliness subscription's callback (:meth:`on_token`) and the count it keeps.

    ``zid`` is the service's own (its token is left out); nothing is counted once ``stop`` is
    set.
    """

    def __init__(
        self,
        outputs: Outputs,
        group: Group,
        gate: LogGate,
        *,
        zid: str,
        stop: threading.Event,
    ) -> None:
        self._tag_key = outputs.tag_key
        self._share_group = group.share_group
        self._log = LimitedLog(log, gate)
        self._zid = zid
        self._stop = stop
        self._lock = threading.Lock()
        #: The other services' tokens seen (their appearances: one that comes back counts
        #: again).
        self.count = 0

    def on_token(self, sample: zenoh.Sample) -> None:
        """Another perception service's liveliness token appeared (ours is left out).

        Anyone may declare tokens under the key: one rate limit for the event, whatever the
        name, and only a count kept.
        """
        other = str(sample.key_expr).rsplit("/", 1)[-1]
        if self._stop.is_set() or sample.kind != zenoh.SampleKind.PUT or other == self._zid:
            return
        if self._share_group:
            return  # the members of a group share the keys by design, one holder a stream
        with self._lock:
            self.count += 1
        self._log(
            logging.WARNING,
            "another_service",
            "another_service",
            zid=other,
            liveliness=str(sample.key_expr),
            tag=self._tag_key,
            detail="another perception service runs here; on the same keys every tag and "
            "record is published twice: give each its own keys, or start each with the "
            "same --share-group NAME to divide the cameras between them",
        )
